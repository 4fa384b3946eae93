"""The one base class of every error driveopt raises on bad input.

Each module defines its own errors (``ProblemError`` in :mod:`driveopt.scene`, ``ConfigError`` in
:mod:`driveopt.config`, ``CheckpointError`` in :mod:`driveopt.learned.checkpoint`, ...) as subclasses
of :class:`DriveoptError`. The command line reports a ``DriveoptError`` on one line and exits with
status 2; any other exception is a bug and keeps its traceback.
"""

from __future__ import annotations


class DriveoptError(ValueError):
    """Bad input: a malformed file, an unknown name, a value out of range, an unusable checkpoint.

    It is a ``ValueError`` so that callers who caught ``ValueError`` before keep working.
    """


class UnknownNameError(DriveoptError):
    """A name (planner, scenario, problem, backend) that is not registered; the message lists the valid ones."""
