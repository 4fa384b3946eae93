"""Resumable JSON-lines results of the offline benchmarks: the first line holds the run's settings, one line per row after.

A rerun with the same settings continues after the rows already written (a line torn by an interruption, and
everything after it, is dropped and redone); a rerun with other settings is refused rather than mixing two runs
in one file.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable, TypeVar

T = TypeVar("T")


def resume_rows(path: str | Path, settings: dict[str, Any], parse: Callable[[dict[str, Any]], T], error: type[Exception],
                what: str) -> list[T]:
    """``parse`` of every complete row of ``path`` written with ``settings``; a new file is started with them.

    ``parse`` turns one record into the caller's row and raises KeyError, TypeError or ValueError for an
    incomplete one, which ends the rows kept. ``error`` (a one-line message naming ``what`` the file should be) when
    ``path`` is not such a file or holds rows of other settings.
    """
    path = Path(path)
    lines = path.read_text().splitlines() if path.exists() else []
    if not lines:
        path.write_text(json.dumps({"settings": settings}) + "\n")
        return []
    try:
        earlier = json.loads(lines[0])["settings"]
        changed = sorted(k for k in set(earlier) | set(settings) if earlier.get(k) != settings.get(k))
    except (json.JSONDecodeError, KeyError, TypeError, AttributeError):
        raise error(f"{path} is not a {what} results file: remove it or choose another --json") from None
    if changed:
        raise error(f"{path} holds results of other settings ({', '.join(changed)}): remove it or choose another --json")
    rows, kept = [], lines[:1]
    for line in lines[1:]:
        try:
            rows.append(parse(json.loads(line)))
        except (json.JSONDecodeError, KeyError, TypeError, ValueError):
            break  # an interrupted write: redo from here
        kept.append(line)
    path.write_text("".join(f"{line}\n" for line in kept))
    return rows
