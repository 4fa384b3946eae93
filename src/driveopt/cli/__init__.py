"""The ``driveopt`` command: ``plan | problems | drive | bench | reproduce | summarise | collect | train | plot-prior |
plot-curves | trace-episode | closed-loop-ab | commonroad | scenarios | planners``.

One module per command, each with ``register(subparsers)``. Errors in user input (a
:class:`~driveopt.errors.DriveoptError`: unknown name, malformed file or config, unusable
checkpoint) print one line ``driveopt: error: ...`` on stderr and exit with status 2; Ctrl-C prints
``driveopt: interrupted`` (and what the command kept, when it says) and exits with status 130, SIGTERM
``driveopt: terminated`` the same way with status 143, within two seconds whatever the command is doing
(:mod:`driveopt.cli.interrupts`); a reader of stdout that goes away (``driveopt plan | head -1``) ends it
quietly with status 141; any other exception is a bug and keeps its traceback (status 1). Every warning is one line
``driveopt: warning: ...``.

Run as the program (``main()`` without arguments: the ``driveopt`` script, ``python -m driveopt.cli``), ``main``
does not return: it ends the process itself (:func:`driveopt.cli.interrupts.exit_process`), so that a signal at any
moment from its first line to the last output ends it with 130 / 143 and the one line, never with Python's default
handling or a crash in the interpreter's teardown. Called with arguments (``main(["plan", ...])``, from Python) it
returns the status and leaves the warnings' format alone.

``driveopt --help``, each command's ``--help`` and the listings (``scenarios``, ``planners``, ``problems``) import
neither JAX nor highway-env nor Flax: every command module imports them inside its run function. Commands that
compile use JAX's persistent compilation cache (:mod:`driveopt.compilation_cache`; ``DRIVEOPT_COMPILATION_CACHE=0``
turns it off).
"""

from __future__ import annotations

import argparse
import signal
import sys
import warnings
from collections.abc import Sequence
from typing import NoReturn

from driveopt.cli import (
    bench,
    closed_loop_ab,
    collect,
    commonroad,
    drive,
    interrupts,
    listing,
    plan,
    plot_curves,
    plot_prior,
    reproduce,
    summarise,
    trace_episode,
    train,
)
from driveopt.cli.common import UsageError
from driveopt.cli.parser import OneLineArgumentParser
from driveopt.errors import DriveoptError

__all__ = ["UsageError", "build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    from driveopt import __version__

    parser = OneLineArgumentParser(prog="driveopt", description="Bi-level motion planning for dense highway traffic.")
    parser.add_argument("--version", action="version", version=f"driveopt {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for command in (plan, drive, bench, reproduce, summarise, collect, train, plot_prior, plot_curves, trace_episode,
                    closed_loop_ab, commonroad, listing):
        command.register(sub)
    return parser


def stop_cleanly_on_signals(program: str | None = None) -> None:
    """For a long job's entry point (the CLI, the benchmark scripts), in the main thread: Ctrl-C and SIGTERM unwind
    as ``KeyboardInterrupt`` (files are closed, the finished work is kept, a rerun resumes) and end the process
    within two seconds with status 130 or 143, even from inside a compiled call (:func:`interrupts.install`).
    ``program`` names it in the one-line message (default: the script's name)."""
    interrupts.install(program or interrupts.default_program())


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command ``argv`` and return its status; without ``argv``, run the command line's and end the process
    with its status (see the module docstring)."""
    if argv is None:
        _run_program()
    return _run_command(argv)


def _run_program() -> NoReturn:
    """The process as ``driveopt``: signal handling from the first line, one-line warnings, the command, then
    :func:`interrupts.exit_process`. Only the first signal raises (and only until :func:`interrupts.stop_raising`),
    so the outer ``except`` catches it wherever it lands, and nothing after can be interrupted."""
    _one_line_warnings()
    try:
        stop_cleanly_on_signals("driveopt")  # its last step sets the handlers: a signal from then on is caught here
        status = _status_of_command(sys.argv[1:])
        interrupts.stop_raising()
    except KeyboardInterrupt as exc:  # the signal, landing where the command's own handling could not catch it
        status = _interrupted(_first_line(exc))
    interrupts.exit_process(status)


def _status_of_command(argv: Sequence[str]) -> int:
    """:func:`_run_command`'s status, with what would otherwise leave the process by Python's exit turned into one:
    ``SystemExit`` (``--help``, a usage error) its code, a bug its traceback and 1."""
    try:
        status = _run_command(argv)
    except SystemExit as exc:
        if exc.code is None or isinstance(exc.code, int):
            return exc.code or 0
        print(exc.code, file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        raise
    except BaseException:
        sys.excepthook(*sys.exc_info())
        return 1
    return 0 if status is None else status


def _run_command(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    stop_cleanly_on_signals("driveopt")
    try:
        status = args.func(args)
        sys.stdout.flush()  # here, where a reader that went away can still be told from a bug
    except DriveoptError as exc:
        print(f"driveopt: error: {_first_line(exc) or type(exc).__name__}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # a command may re-raise it with what it kept as the message
        return _interrupted(_first_line(exc))
    except BrokenPipeError as exc:
        if interrupts.stdout_closed(exc):
            return interrupts.BROKEN_PIPE_STATUS
        raise
    if interrupts.stop_status() is not None:  # the command swallowed the signal's exception: it stops all the same
        return _interrupted("")
    return status


def _one_line_warnings() -> None:
    """In the ``driveopt`` process only: every warning printed as one line ``driveopt: warning: MESSAGE`` (the
    message's lines joined), without Python's file, line number, category and source line, which speak to a
    developer rather than to the user of a command."""
    warnings.formatwarning = _format_warning


def _format_warning(message, category, filename, lineno, line=None) -> str:
    text = " ".join(part.strip() for part in str(message).splitlines() if part.strip())
    return f"driveopt: warning: {text or category.__name__}\n"


def _interrupted(detail: str) -> int:
    """Write the one line for the stopping signal and return its status; for a KeyboardInterrupt raised without a
    signal (by a caller of :func:`main`), ``driveopt: interrupted`` and 130."""
    if interrupts.stop_status() is None:
        print(f"driveopt: interrupted: {detail}" if detail else "driveopt: interrupted", file=sys.stderr)
        return 128 + signal.SIGINT
    interrupts.announce(detail)
    return interrupts.stop_status()


def _first_line(exc: BaseException) -> str:
    return str(exc).splitlines()[0] if str(exc) else ""


if __name__ == "__main__":
    sys.exit(main())
