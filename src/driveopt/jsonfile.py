"""The one reader of JSON input files (problem files, planner-config files, scenario override files).

Every input file goes through :func:`read_json`, which refuses, with a one-line error naming the file,
anything that could hang, exhaust memory or crash the parser before a value reaches the code that checks
it:

* a path that is not a regular file (a FIFO would block forever, ``/dev/zero`` never ends, a directory
  has no text), found with ``stat`` before opening and ``fstat`` on the non-blocking descriptor after, so
  nothing is read from it;
* a file larger than :data:`MAX_BYTES` (input files are a few kilobytes);
* bytes that are not UTF-8, and strings that are not valid Unicode (a lone surrogate such as
  ``"\\ud800"`` parses, but cannot be written back out);
* arrays and objects nested deeper than :data:`MAX_DEPTH` (Python's parser recurses, and a deep file
  overflows its stack);
* number literals longer than :data:`MAX_NUMBER_LENGTH` characters (a 400-digit integer overflows every
  float conversion downstream), numbers that overflow to infinity (``1e400``), and the non-standard
  constants ``NaN``, ``Infinity`` and ``-Infinity``;
* an object with the same key twice (JSON keeps the last silently, so the first value would be ignored).
"""

from __future__ import annotations

import itertools
import json
import math
import os
import re
import stat
from pathlib import Path
from typing import Any

from driveopt.errors import DriveoptError

MAX_BYTES = 10 * 2**20  # [bytes] largest input file read (problem and config files are a few KB)
MAX_DEPTH = 64  # [-] deepest nesting of arrays and objects (the input formats need at most 3)
MAX_NUMBER_LENGTH = 32  # [characters] longest number literal (a float's shortest repr needs at most 24)


class JSONFileError(DriveoptError):
    """An input file that cannot be read as JSON within the limits above."""


def read_json(path: str | Path, what: str = "JSON file", error: type[DriveoptError] = JSONFileError) -> Any:
    """The JSON value in ``path``, after the checks of the module docstring; ``error`` (a DriveoptError
    subclass) naming ``what`` and the path otherwise. A missing path says "no such file"."""
    label = f"{what} {path}"
    raw = _read_regular_file(Path(path), label, error)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{label}: not UTF-8 text (byte {exc.start})") from None
    return parse_json(text, label, error)


def parse_json(text: str, label: str = "JSON text", error: type[DriveoptError] = JSONFileError) -> Any:
    """``json.loads(text)`` within the limits of the module docstring; ``error`` starting with ``label`` otherwise."""
    if nesting_depth(text) > MAX_DEPTH:
        raise error(f"{label}: nested deeper than {MAX_DEPTH} levels")
    try:
        value = json.loads(text, parse_int=_parse_int, parse_float=_parse_float, parse_constant=_refuse_constant,
                           object_pairs_hook=_object_without_duplicates)
    except json.JSONDecodeError as exc:
        raise error(f"{label}: not valid JSON ({exc.msg} at line {exc.lineno} column {exc.colno})") from None
    except _LiteralError as exc:
        raise error(f"{label}: {exc}") from None
    bad = _invalid_string(value) if _SURROGATE_ESCAPE.search(text) else None  # UTF-8 text cannot hold one otherwise
    if bad is not None:
        raise error(f"{label}: string {bad!r} is not valid Unicode (a lone surrogate)")
    return value


def _read_regular_file(path: Path, label: str, error: type[DriveoptError]) -> bytes:
    """The bytes of ``path``, refused unless it is a regular file of at most MAX_BYTES: checked before opening (a
    device is never opened), and again on the descriptor, opened without blocking (were the path swapped for a
    FIFO in between, it would open at once and be refused, not block)."""
    _check_regular(_opened(os.stat, path, label, error).st_mode, label, error)
    fd = _opened(os.open, path, label, error, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    try:
        info = os.fstat(fd)
        _check_regular(info.st_mode, label, error)
        if info.st_size > MAX_BYTES:
            raise error(f"{label}: {info.st_size} bytes, more than the {MAX_BYTES // 2**20} MB an input file may have")
        raw = _read_at_most(fd, MAX_BYTES + 1)
    except OSError as exc:
        raise error(f"{label}: cannot read ({exc.strerror or exc})") from None
    finally:
        os.close(fd)
    if len(raw) > MAX_BYTES:  # it grew while being read
        raise error(f"{label}: more than the {MAX_BYTES // 2**20} MB an input file may have")
    return raw


def _opened(call: Any, path: Path, label: str, error: type[DriveoptError], *args: Any) -> Any:
    """``call(path, *args)`` (``os.stat``, ``os.open``), its OSError as ``error``: "no such file" when missing."""
    try:
        return call(path, *args)
    except FileNotFoundError:
        raise error(f"{label}: no such file") from None
    except (OSError, ValueError) as exc:  # ValueError: a path with a NUL byte
        raise error(f"{label}: cannot open ({getattr(exc, 'strerror', None) or exc})") from None


def _check_regular(mode: int, label: str, error: type[DriveoptError]) -> None:
    if not stat.S_ISREG(mode):
        raise error(f"{label}: not a regular file ({_kind(mode)})")


def _read_at_most(fd: int, size: int) -> bytes:
    chunks = []
    while size > 0:
        chunk = os.read(fd, min(size, 2**20))
        if not chunk:
            break
        chunks.append(chunk)
        size -= len(chunk)
    return b"".join(chunks)


def _kind(mode: int) -> str:
    kinds = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
             (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))
    return next((name for test, name in kinds if test(mode)), "not a plain file")


_STRING = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)
_NOT_BRACKET = re.compile(r"[^\[\]{}]+")
_STEP = {"[": 1, "{": 1, "]": -1, "}": -1}
_SURROGATE_ESCAPE = re.compile(r"\\u[dD][89a-fA-F]")


def nesting_depth(text: str) -> int:
    """Deepest nesting of arrays and objects in JSON ``text`` (brackets inside strings do not count), counted
    without recursion."""
    brackets = _NOT_BRACKET.sub("", _STRING.sub('""', text))
    return max(itertools.accumulate(map(_STEP.__getitem__, brackets)), default=0)


class _LiteralError(ValueError):
    """A number literal or constant beyond the limits (raised inside the parser, reported by parse_json)."""


def _check_length(literal: str) -> None:
    if len(literal) > MAX_NUMBER_LENGTH:
        raise _LiteralError(f"number {literal[:12]}... has {len(literal)} characters, more than {MAX_NUMBER_LENGTH}")


def _parse_int(literal: str) -> int:
    _check_length(literal)
    return int(literal)


def _parse_float(literal: str) -> float:
    _check_length(literal)
    value = float(literal)
    if not math.isfinite(value):
        raise _LiteralError(f"number {literal} is beyond the range of a float")
    return value


def _refuse_constant(name: str) -> Any:
    raise _LiteralError(f"{name} is not a JSON number; give a finite number")


def _object_without_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    data: dict[str, Any] = {}
    for key, value in pairs:
        if key in data:
            raise _LiteralError(f"key {key!r} appears twice in one object")
        data[key] = value
    return data


def _invalid_string(value: Any) -> str | None:
    """The first string (value or key) of a parsed JSON value that is not valid Unicode, or None; iterative,
    so it needs no recursion."""
    pending = [value]
    while pending:
        item = pending.pop()
        if isinstance(item, str):
            if not is_valid_unicode(item):
                return item
        elif isinstance(item, dict):
            pending.extend(item.keys())
            pending.extend(item.values())
        elif isinstance(item, list):
            pending.extend(item)
    return None


def is_valid_unicode(text: str) -> bool:
    """Whether ``text`` can be written out as UTF-8 (a lone surrogate such as "\\ud800" cannot)."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True
