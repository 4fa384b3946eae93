"""The command line's argument parser and the argument types that check a value's range when it is parsed.

:class:`OneLineArgumentParser` reports a usage error (a missing or unknown option, a value its type
refuses) the way every other user error is reported: one line ``driveopt: error: ...`` on stderr and
exit status 2, without argparse's usage block (``--help`` still prints it). Its ``--help`` shows every option's
default (:class:`DefaultsHelpFormatter`). Subcommand parsers made with ``add_subparsers`` are of the same class, so
both rules hold for every command.
"""

from __future__ import annotations

import argparse
from typing import NoReturn


class DefaultsHelpFormatter(argparse.HelpFormatter):
    """``--help`` with each option's default after its help, ``(default: VALUE)``: ``none`` for an option that is off
    unless given, ``off`` for a flag; an option whose help already says its default (``(default: the scenario's)``)
    is left as written. Positional arguments and required options have no default to show."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if ("default" in text.lower() or not action.option_strings or action.required
                or action.default is argparse.SUPPRESS or isinstance(action, (argparse._HelpAction, argparse._VersionAction))):
            return text
        return f"{text} (default: {_default_text(action)})"


def _default_text(action: argparse.Action) -> str:
    default = action.default
    if isinstance(action, argparse._StoreTrueAction):
        return "on" if default else "off"
    if isinstance(action, argparse._StoreFalseAction):
        return "off" if default is False else "on"
    if default is None:
        return "none"
    if isinstance(default, (list, tuple)):
        return " ".join(str(value) for value in default) or "none"
    return str(default).replace("%", "%%")  # argparse formats the help string with %


class OneLineArgumentParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line ``driveopt: error: <message>`` and exit status 2, and whose
    ``--help`` shows every option's default."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", DefaultsHelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        first = message.splitlines()[0] if message else "invalid arguments"
        self.exit(2, f"driveopt: error: {first} (see {self.prog} --help)\n")


def duration(text: str) -> float:
    """Argument type of ``--duration`` [s]: a finite number in (0, MAX_DURATION], the range of a scenario's
    duration, so that ``1e308`` is refused when parsed rather than overflowing a step count later."""
    from driveopt.sim.scenarios import ScenarioError, check_duration  # the simulator's package loads in seconds

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a duration in seconds, got {text!r}") from None
    try:
        return check_duration(value)
    except ScenarioError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def latency(text: str) -> str | float | None:
    """Argument type of ``--latency``: ``sync`` (None: the simulator waits for every plan), ``measured``, or a compute
    time in milliseconds in [0, MAX_LATENCY_MS] (a float); :mod:`driveopt.drivers.latency`."""
    from driveopt.drivers.latency import LatencyError, parse_latency

    try:
        return parse_latency(text).option
    except LatencyError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
