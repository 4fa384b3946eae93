"""Resumable JSON-lines results of the offline benchmarks: the first line holds the run's settings, one line per row after.

A rerun with the same settings continues after the rows already written (a line torn by an interruption, and
everything after it, is dropped and redone); a rerun with other settings is refused rather than mixing two runs
in one file. The file is rewritten whole (:func:`driveopt.files.atomic_write`) and its lines are strict JSON
(:func:`row_line`: no NaN or Infinity, a missing number is null).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable, TypeVar

from driveopt.files import atomic_write, json_text, refuse_constant
from driveopt.jsonfile import MAX_DEPTH, nesting_depth

T = TypeVar("T")


def row_line(record: dict[str, Any]) -> str:
    """One line of a results file: ``record`` as strict JSON on one line, with its newline."""
    return json_text(record, indent=None) + "\n"


def resume_rows(path: str | Path, settings: dict[str, Any], parse: Callable[[dict[str, Any]], T], error: type[Exception],
                what: str) -> list[T]:
    """``parse`` of every complete row of ``path`` written with ``settings``; a new file is started with them.

    ``parse`` turns one record into the caller's row and raises KeyError, TypeError or ValueError for an
    incomplete one, which ends the rows kept. ``error`` (a one-line message naming ``what`` the file should be) when
    ``path`` is not such a file or holds rows of other settings.
    """
    path = Path(path)
    lines = _lines(path, error)
    if not lines:
        atomic_write(path, row_line({"settings": settings}).encode())
        return []
    try:
        earlier = _loads(lines[0], strict=True)["settings"]
        now = json.loads(json_text(settings))  # as the file holds them: lists for tuples, null for NaN
        changed = sorted(k for k in set(earlier) | set(now) if earlier.get(k) != now.get(k))
    except (UnicodeDecodeError, ValueError, KeyError, TypeError, AttributeError):
        raise error(f"{path} is not a {what} results file: remove it or choose another --json") from None
    if changed:
        raise error(f"{path} holds results of other settings ({', '.join(changed)}): remove it or choose another --json")
    rows, kept = [], lines[:1]
    for line in lines[1:]:
        try:
            rows.append(parse(_loads(line)))
        except (UnicodeDecodeError, ValueError, KeyError, TypeError):
            break  # an interrupted write: redo from here
        kept.append(line)
    atomic_write(path, b"".join(line + b"\n" for line in kept))
    return rows


def _lines(path: Path, error: type[Exception]) -> list[bytes]:
    """The non-empty lines of ``path`` (none when it does not exist); ``error`` when it cannot be read."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return []
    except OSError as exc:
        raise error(f"{path} cannot be read ({exc.strerror or exc}): choose another --json") from None
    return [line for line in data.split(b"\n") if line.strip()]


def _loads(line: bytes, strict: bool = False) -> Any:
    """The JSON value of ``line`` (``strict``: NaN and Infinity refused); ValueError, as for any malformed line, when it
    is nested deeper than an input file may be (:data:`driveopt.jsonfile.MAX_DEPTH`): Python's parser recurses, and a
    deep line would overflow its stack."""
    text = line.decode("utf-8")
    if nesting_depth(text) > MAX_DEPTH:
        raise ValueError(f"nested deeper than {MAX_DEPTH} levels")
    return json.loads(text, parse_constant=refuse_constant) if strict else json.loads(text)
