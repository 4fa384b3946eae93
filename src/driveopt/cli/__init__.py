"""The ``driveopt`` command: ``plan | problems | drive | bench | summarise | collect | train | plot-prior | plot-curves |
scenarios | planners``.

One module per command, each with ``register(subparsers)``. Errors in user input (a
:class:`~driveopt.errors.DriveoptError`: unknown name, malformed file or config, unusable
checkpoint) print one line ``driveopt: error: ...`` on stderr and exit with status 2; Ctrl-C prints
``driveopt: interrupted`` (and what the command kept, when it says) and exits with status 130;
SIGTERM unwinds the same way silently, with status 143; any other exception is a bug and keeps its
traceback.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Sequence

from driveopt.cli import bench, collect, drive, listing, plan, plot_curves, plot_prior, summarise, train
from driveopt.cli.common import UsageError
from driveopt.errors import DriveoptError

__all__ = ["UsageError", "build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="driveopt", description="Bi-level motion planning for dense highway traffic.")
    sub = parser.add_subparsers(dest="command", required=True)
    for command in (plan, drive, bench, summarise, collect, train, plot_prior, plot_curves, listing):
        command.register(sub)
    return parser


def _exit_on_sigterm(signum, frame) -> None:
    raise SystemExit(128 + signum)


def stop_cleanly_on_signals() -> None:
    """For a long job's entry point (the CLI, the benchmark scripts); only in the main thread."""
    if threading.current_thread() is threading.main_thread():
        # A terminated long job (collect, train, bench) unwinds like Ctrl-C: files are closed, the
        # finished work is kept, and a rerun resumes.
        signal.signal(signal.SIGTERM, _exit_on_sigterm)
        # Ctrl-C interrupts even where the shell that started us ignored SIGINT (a background job of a
        # script, which Python would otherwise inherit): the long jobs stop cleanly either way.
        signal.signal(signal.SIGINT, signal.default_int_handler)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    stop_cleanly_on_signals()
    try:
        return args.func(args)
    except DriveoptError as exc:
        print(f"driveopt: error: {_first_line(exc) or type(exc).__name__}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # a command may re-raise it with what it kept as the message
        detail = _first_line(exc)
        print(f"driveopt: interrupted: {detail}" if detail else "driveopt: interrupted", file=sys.stderr)
        return 128 + signal.SIGINT


def _first_line(exc: BaseException) -> str:
    return str(exc).splitlines()[0] if str(exc) else ""


if __name__ == "__main__":
    sys.exit(main())
