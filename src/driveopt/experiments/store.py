"""Append-only JSONL store of episode records: the unit of resumption for ``driveopt bench``.

One line per finished episode, flushed and fsynced as soon as the episode ends. A run that is
interrupted loses at most the episodes in flight; a rerun reads the finished keys and skips them.
A line cut short by a crash (no trailing newline / invalid JSON at the end of the file) is
dropped on load and rewritten by the rerun; invalid JSON anywhere else is reported as corruption.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Iterable, NamedTuple

from driveopt.errors import DriveoptError

SCHEMA_VERSION = 1


class StoreError(DriveoptError):
    """The results file is corrupted or was written by an incompatible version."""


class JobKey(NamedTuple):
    scenario: str
    planner: str
    seed: int
    episode: int

    @property
    def env_seed(self) -> int:
        """Traffic seed of this episode: the same for every planner (same traffic for all)."""
        return self.seed * 100_003 + self.episode


def key_of(record: dict[str, Any]) -> JobKey:
    return JobKey(record["scenario"], record["planner"], int(record["seed"]), int(record["episode"]))


def load_records(path: str | Path) -> list[dict[str, Any]]:
    """All complete records of a results file (empty when it does not exist)."""
    path = Path(path)
    if not path.exists():
        return []
    lines = path.read_text().split("\n")
    records = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            if number == len(lines):  # a final line cut short by an interruption
                continue
            raise StoreError(f"{path}:{number}: corrupted line (not JSON)") from None
        if not isinstance(record, dict) or record.get("schema") != SCHEMA_VERSION:
            raise StoreError(f"{path}:{number}: not a driveopt bench record of schema {SCHEMA_VERSION}")
        records.append(record)
    return records


def repair(path: str | Path) -> None:
    """Drop a trailing partial line so that appends start on a fresh line."""
    path = Path(path)
    if not path.exists():
        return
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        path.write_bytes(data[: data.rfind(b"\n") + 1])


def append_record(path: str | Path, record: dict[str, Any]) -> None:
    """Append one record durably (write, flush, fsync)."""
    line = json.dumps({"schema": SCHEMA_VERSION, **record}, separators=(",", ":")) + "\n"
    with open(path, "a", encoding="utf-8") as f:
        f.write(line)
        f.flush()
        os.fsync(f.fileno())


def pending(jobs: Iterable[JobKey], records: Iterable[dict[str, Any]]) -> list[JobKey]:
    """Jobs that have no record yet, in their original order."""
    done = {key_of(r) for r in records}
    return [job for job in jobs if job not in done]
