"""Append-only JSONL store of episode records: the unit of resumption for ``driveopt bench``.

A bench output folder holds ``spec.json`` (the settings of its episodes: options and the digests of the learned
weights) and ``episodes.jsonl``, one line per finished episode, flushed and fsynced as soon as the episode ends. A
run that is interrupted loses at most the episodes in flight; a rerun reads the finished keys and skips them. A final
line cut short by a crash (no trailing newline) is not a record: it is ignored on load and cut off before the rerun
appends.

Every record is checked when read: strict JSON in UTF-8 nested at most as deep as an input file may be
(:data:`driveopt.jsonfile.MAX_DEPTH`), the fields a summary counts with their types, one record per job, one of the
jobs the folder's ``spec.json`` declares (its scenarios, planners, seeds, episodes and episode list, which grow as
later runs extend the folder) and (for records that name their settings) the settings of that ``spec.json``. Anything
else is refused with the file and line number, never counted; so is a folder whose records have no ``spec.json`` to
say how they were run.
"""

from __future__ import annotations

import json
import math
import numbers
import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, NamedTuple

from driveopt.errors import DriveoptError
from driveopt.files import atomic_write, json_digest, json_text, refuse_constant
from driveopt.jsonfile import MAX_DEPTH, nesting_depth

SCHEMA_VERSION = 1
RECORDS_FILE = "episodes.jsonl"
SPEC_FILE = "spec.json"
ENV_SEED_STRIDE = 100_003  # traffic seed of an episode: seed * ENV_SEED_STRIDE + episode
MAX_ENV_SEED = 2**32 - 1  # traffic seeds feed JAX's 32-bit PRNG seed and highway-env's generator, as `drive --seed`


def highest_seed(episodes: int) -> int:
    """The largest seed whose ``episodes`` episodes all have traffic seeds (:attr:`JobKey.env_seed`) within
    [0, MAX_ENV_SEED]: beyond it JAX's 32-bit seed would repeat another episode's randomness, or overflow."""
    return (MAX_ENV_SEED - max(episodes - 1, 0)) // ENV_SEED_STRIDE


def seed_range_problem(seed: int, episodes: int) -> str | None:
    """Why ``seed`` cannot drive ``episodes`` episodes (outside [0, :func:`highest_seed`]), naming the range; None
    when it can."""
    highest = highest_seed(episodes)
    if 0 <= seed <= highest:
        return None
    return (f"seed {seed!r} is out of range: seeds are integers from 0 to {highest} with {episodes} episodes (traffic "
            f"seed = seed x {ENV_SEED_STRIDE} + episode, at most {MAX_ENV_SEED})")


class StoreError(DriveoptError):
    """The results file is corrupted, holds a record twice or of other settings, or was written by an incompatible
    version."""


class JobKey(NamedTuple):
    scenario: str
    planner: str
    seed: int
    episode: int

    @property
    def env_seed(self) -> int:
        """Traffic seed of this episode: the same for every planner (same traffic for all)."""
        return self.seed * ENV_SEED_STRIDE + self.episode


def key_of(record: dict[str, Any]) -> JobKey:
    return JobKey(record["scenario"], record["planner"], int(record["seed"]), int(record["episode"]))


def _is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    """A finite real number, not a bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


# (field, what it must be, the check): the fields the summaries count, each with its JSON type
_REQUIRED: tuple[tuple[str, str, Callable[[Any], bool]], ...] = (
    ("scenario", "a non-empty string", lambda v: isinstance(v, str) and bool(v)),
    ("planner", "a non-empty string", lambda v: isinstance(v, str) and bool(v)),
    ("seed", "an integer >= 0", lambda v: _is_int(v) and v >= 0),
    ("episode", "an integer >= 0", lambda v: _is_int(v) and v >= 0),
    ("collided", "true or false", lambda v: isinstance(v, bool)),
    ("off_road", "true or false", lambda v: isinstance(v, bool)),
    ("mean_speed", "a finite number", _is_number),
    ("sim_seconds", "a finite number >= 0", lambda v: _is_number(v) and v >= 0),
    ("plan_seconds", "a finite number >= 0", lambda v: _is_number(v) and v >= 0),
)
_OPTIONAL: tuple[tuple[str, str, Callable[[Any], bool]], ...] = (
    ("plan_ms", "a list of finite numbers", lambda v: isinstance(v, list) and all(_is_number(x) for x in v)),
    ("device", "a string", lambda v: isinstance(v, str)),
    ("settings", "a string", lambda v: isinstance(v, str)),
    ("code", "a string", lambda v: isinstance(v, str)),  # digest of the driveopt sources that ran the episode
    ("cpu_model", "a string", lambda v: isinstance(v, str)),  # the processor model it planned on
    ("jax", "a string", lambda v: isinstance(v, str)),  # the jax version that ran it
    ("numpy", "a string", lambda v: isinstance(v, str)),  # the numpy version
    ("lockstep", "an integer >= 1", lambda v: _is_int(v) and v >= 1),  # episodes per planning call (lock-step runs)
)


def record_problem(record: Any) -> str | None:
    """What is wrong with ``record`` as a bench record (a missing or mistyped field, another schema); None when
    nothing is."""
    if not isinstance(record, dict):
        return f"not a JSON object but {type(record).__name__}"
    if record.get("schema") != SCHEMA_VERSION:
        return f"not a driveopt bench record of schema {SCHEMA_VERSION}"
    for name, expected, valid in _REQUIRED:
        if name not in record:
            return f"no field '{name}'"
        if not valid(record[name]):
            return f"'{name}' must be {expected}, got {record[name]!r}"
    for name, expected, valid in _OPTIONAL:
        if name in record and not valid(record[name]):
            return f"'{name}' must be {expected}, got {record[name]!r}"
    return None


class _Line(NamedTuple):
    number: int
    record: dict[str, Any]


def _read_lines(path: Path) -> list[_Line]:
    """The checked records of ``path`` with their line numbers; StoreError (file:line) for anything else."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return []
    except OSError as exc:
        raise StoreError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    lines = data.split(b"\n")[:-1]  # what follows the last newline is an interrupted write, not a record
    checked: list[_Line] = []
    first: dict[JobKey, int] = {}
    for number, raw in enumerate(lines, start=1):
        if not raw.strip():
            continue
        record = _parse(path, number, raw)
        key = key_of(record)
        if key in first:
            raise StoreError(f"{path}:{number}: {key.planner} on {key.scenario}, seed {key.seed}, episode {key.episode} "
                             f"again (first on line {first[key]}); each episode is counted once: remove one of them")
        first[key] = number
        checked.append(_Line(number, record))
    return checked


def _parse(path: Path, number: int, raw: bytes) -> dict[str, Any]:
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise StoreError(f"{path}:{number}: corrupted line (not UTF-8 text)") from None
    if nesting_depth(text) > MAX_DEPTH:  # Python's parser recurses: a deep line would overflow its stack
        raise StoreError(f"{path}:{number}: corrupted line (nested deeper than {MAX_DEPTH} levels; a bench record has 2)")
    try:
        record = json.loads(text, parse_constant=refuse_constant)
    except ValueError as exc:  # JSONDecodeError, NaN or Infinity
        raise StoreError(f"{path}:{number}: corrupted line (not JSON: {str(exc).splitlines()[0]})") from None
    problem = record_problem(record)
    if problem:
        raise StoreError(f"{path}:{number}: {problem}")
    return record


def load_records(path: str | Path) -> list[dict[str, Any]]:
    """All complete records of a results file, each checked (:func:`record_problem`, one per job); empty when the
    file does not exist. It does not look at the folder's spec: :func:`load_folder` does."""
    return [line.record for line in _read_lines(Path(path))]


def settings_digest(options: dict[str, Any], weights: str | None) -> str:
    """16 hex digits naming the settings an episode ran with: the bench ``options`` and the digest of the learned
    weights its planner drove with on its scenario (None: none)."""
    return json_digest({"options": options, "weights": weights})


def expected_settings(spec: dict[str, Any], scenario: str, planner: str) -> str:
    """:func:`settings_digest` of an episode of ``planner`` on ``scenario`` under a folder's ``spec.json``."""
    return settings_digest(spec["options"], spec["weights"].get(f"{planner}/{scenario}"))


def read_spec(path: str | Path) -> dict[str, Any] | None:
    """The contents of a ``spec.json`` (at least ``options`` and ``weights``, both objects); None when it does not
    exist, StoreError when it cannot be read or is malformed."""
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
        if nesting_depth(text) > MAX_DEPTH:  # Python's parser recurses: a deep file would overflow its stack
            raise ValueError(f"nested deeper than {MAX_DEPTH} levels")
        spec = json.loads(text, parse_constant=refuse_constant)
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise StoreError(f"{path} is unreadable ({str(exc).splitlines()[0]}); remove it or use another output folder") from None
    if not (isinstance(spec, dict) and isinstance(spec.get("options"), dict)
            and all(isinstance(spec.get(name, {}), dict) for name in DIGESTS)):
        raise StoreError(f"{path} is not a bench spec (an object with 'options', 'weights' and 'configs'); remove it or "
                         "use another output folder")
    return {**spec, **{name: spec.get(name, {}) for name in DIGESTS}}


DIGESTS = ("weights", "configs")  # spec.json's digests: the learned weights of each ``planner/scenario``, the
# configuration of each planner (folders written before the configurations were named have none: nothing to compare)


def clashing(old: dict[str, Any], new: dict[str, Any], name: str) -> list[str]:
    """The keys whose digest under ``name`` (one of :data:`DIGESTS`) differs between two spec.json contents."""
    return sorted(key for key in set(old[name]) & set(new[name]) if old[name][key] != new[name][key])


def merged_spec(old: dict[str, Any] | None, new: dict[str, Any]) -> dict[str, Any]:
    """What a folder's ``spec.json`` says once a run of ``new`` (a spec.json's contents) joins the episodes of ``old``
    (None: none): the folder's scenarios, planners and seeds (``old``'s first), the larger episode count, the episode
    list of both (empty: every episode) and the digests of both (``new``'s where both name one). Several runs
    share a folder (``driveopt reproduce`` runs each arm once for every figure that compares it), so the file names
    what all of them asked for, not only the last one. The options must agree (the caller's check)."""
    if old is None:
        return new

    def union(name: str) -> list:
        return list(dict.fromkeys([*old.get(name, ()), *new.get(name, ())]))

    full = not (old.get("episode_list") and new.get("episode_list"))
    return {**old, **new, "scenarios": union("scenarios"), "planners": union("planners"), "seeds": union("seeds"),
            "episodes": max(old.get("episodes", 0), new.get("episodes", 0)),
            "episode_list": [] if full else sorted(union("episode_list")),
            **{name: {**old.get(name, {}), **new.get(name, {})} for name in DIGESTS}}


def load_folder(location: str | Path) -> tuple[dict[str, Any] | None, list[dict[str, Any]]]:
    """(spec, records) of a bench folder (or of its records file, with ``spec.json`` beside it): the records checked
    as :func:`load_records` does, and each that names its settings against the spec. StoreError when the folder
    holds records but no ``spec.json``: nothing would tell their settings from another run's. A folder without records
    is free, whatever its ``spec.json`` says: (None, [])."""
    path = Path(location)
    records_path = path / RECORDS_FILE if path.is_dir() else path
    lines = _read_lines(records_path)
    if not lines:
        return None, []
    spec_path = records_path.parent / SPEC_FILE
    spec = read_spec(spec_path)
    if spec is None:
        raise StoreError(f"{records_path} holds {len(lines)} episodes but {spec_path} is missing (the settings they "
                         "ran with): restore it, or use another output folder")
    for number, record in lines:
        if "settings" in record and record["settings"] != expected_settings(spec, record["scenario"], record["planner"]):
            raise StoreError(f"{records_path}:{number}: {record['planner']} on {record['scenario']} ran with other "
                             f"settings than {spec_path} holds; it belongs to another run: remove it")
        outside = outside_spec(spec, record)
        if outside:
            raise StoreError(f"{records_path}:{number}: {record['planner']} on {record['scenario']}, seed "
                             f"{_short(record['seed'])}, episode {_short(record['episode'])} is not an episode of the runs "
                             f"{spec_path} describes ({outside}); it belongs to another run: remove it")
    return spec, [line.record for line in lines]


def outside_spec(spec: dict[str, Any], record: dict[str, Any]) -> str | None:
    """How ``record`` (a checked bench record) lies outside the jobs of a folder's ``spec.json`` (:func:`merged_spec`
    of every run that wrote there: its scenarios, planners, seeds, episodes and episode list); None when it is one of
    them. A field the spec does not have (a spec.json of an older driveopt) is not checked."""
    for name, field in (("scenarios", "scenario"), ("planners", "planner"), ("seeds", "seed")):
        declared = spec.get(name)
        if isinstance(declared, list) and record[field] not in declared:
            shown = ", ".join(_short(value) for value in declared)
            return f"{name} {shown}, not {_short(record[field])}"
    episodes, episode_list = spec.get("episodes"), spec.get("episode_list") or []
    if _is_int(episodes) and not record["episode"] < episodes:
        return f"episodes 0 to {episodes - 1}"
    if isinstance(episode_list, list) and episode_list and record["episode"] not in episode_list:
        return f"episode list {', '.join(map(_short, episode_list))}"
    return None


def _short(value: Any) -> str:
    """``value`` for a message: an integer of more than 20 digits by its first digits and length."""
    text = str(value)
    return f"{text[:12]}... ({len(text)} characters)" if len(text) > 20 else text


def repair(path: str | Path) -> None:
    """Cut off a trailing partial line so that appends start on a fresh line (whole: via a renamed copy)."""
    path = Path(path)
    if not path.exists():
        return
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        atomic_write(path, data[: data.rfind(b"\n") + 1])


def append_record(path: str | Path, record: dict[str, Any]) -> None:
    """Append one record durably (write, flush, fsync) as strict JSON; a record the loader would refuse is a bug of
    the episode function (ValueError), and is not written."""
    record = {"schema": SCHEMA_VERSION, **record}
    problem = record_problem(record)
    if problem:
        raise ValueError(f"an episode record to append is malformed: {problem}")
    line = json_text(record, indent=None) + "\n"
    try:
        with open(path, "a", encoding="utf-8") as f:
            f.write(line)
            f.flush()
            os.fsync(f.fileno())
    except OSError as exc:
        raise StoreError(f"cannot append to {path}: {exc.strerror or exc}") from None


def pending(jobs: Iterable[JobKey], records: Iterable[dict[str, Any]]) -> list[JobKey]:
    """Jobs that have no record yet, in their original order."""
    done = {key_of(r) for r in records}
    return [job for job in jobs if job not in done]
