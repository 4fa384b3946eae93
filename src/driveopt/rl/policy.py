"""Policy files of the RL baselines: Stable-Baselines3 zips that carry a driveopt record; loading and checks.

A policy file is what ``model.save`` writes (a zip: ``data``, ``policy.pth``, ...), plus one entry
``driveopt.json``: ``{"format": "driveopt-rl-policy", "schema_version": 1, "algo": "dqn", "steps": N,
"scenario": {...}, "lanes": 2, "settings": {...}, "replay_buffer": {"file": ..., "sha256": ...} | null,
"eval": {...}}``. Stable-Baselines3 ignores the extra entry, so a file loads with ``DQN.load`` too.
Files are written atomically (a temporary file in the same folder, fsynced, renamed), as
:mod:`driveopt.learned.checkpoint` writes its checkpoints; the zip's per-entry CRCs are the checksum
(a truncated or modified file is refused), and a replay buffer saved beside a checkpoint is named in
its record with its SHA-256.

Reading a file checks the zip, the record, the algorithm and (for the planners) the road's lane count,
and raises :class:`PolicyError` with the reason. Stable-Baselines3 and PyTorch are imported only by
:func:`require_rl` (``pip install 'driveopt[rl]'``), never when this module is imported.
"""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
from importlib import resources
from pathlib import Path
from typing import Any

from driveopt.errors import DriveoptError

ALGORITHMS = ("dqn", "ppo")
FORMAT = "driveopt-rl-policy"
SCHEMA_VERSION = 1
RECORD_ENTRY = "driveopt.json"  # the driveopt record inside the Stable-Baselines3 zip
INSTALL_HINT = "pip install 'driveopt[rl]'"
LANE_WORDS = {2: "two", 3: "three", 4: "four", 5: "five"}


class PolicyError(DriveoptError):
    """A policy file that is missing, corrupted, of another algorithm or road, or that does not match its use."""


class MissingExtraError(DriveoptError):
    """Stable-Baselines3 or PyTorch is not installed (the ``rl`` extra)."""


def require_rl() -> Any:
    """The ``stable_baselines3`` module; MissingExtraError (one line naming the install command) without the extra."""
    try:
        import stable_baselines3
        import torch  # noqa: F401  (Stable-Baselines3 needs it; a broken install fails here, not mid-training)
    except ImportError as exc:
        raise MissingExtraError(f"the RL baselines need Stable-Baselines3 and PyTorch ({exc.name or exc} is missing): "
                                f"{INSTALL_HINT}") from None
    return stable_baselines3


def check_algo(algo: str) -> str:
    if algo not in ALGORITHMS:
        raise PolicyError(f"unknown RL algorithm {algo!r}; valid: {', '.join(ALGORITHMS)}")
    return algo


def algorithm_class(algo: str) -> Any:
    """Stable-Baselines3's class of ``algo`` (``DQN`` or ``PPO``)."""
    sb3 = require_rl()
    return {"dqn": sb3.DQN, "ppo": sb3.PPO}[check_algo(algo)]


def lane_word(lanes: int) -> str:
    return LANE_WORDS.get(int(lanes), str(int(lanes)))


def shipped_policy(algo: str, lanes: int) -> Path | None:
    """The policy shipped for ``algo`` on roads with ``lanes`` lanes (``weights/{algo}-{two|four|...}-lane.zip``), or None."""
    path = Path(str(resources.files("driveopt") / "weights" / f"{algo}-{lane_word(lanes)}-lane.zip"))
    return path if path.is_file() else None


def policy_bytes(model: Any, record: dict[str, Any]) -> bytes:
    """The policy file of ``model`` (a Stable-Baselines3 algorithm) with ``record`` as its driveopt entry; without the
    training run's TensorBoard folder (a path of the machine it trained on)."""
    buffer = io.BytesIO()
    model.save(buffer, exclude=["tensorboard_log"])
    with zipfile.ZipFile(buffer, "a", compression=zipfile.ZIP_DEFLATED) as archive:
        archive.writestr(RECORD_ENTRY, json.dumps({"format": FORMAT, "schema_version": SCHEMA_VERSION, **record}))
    return buffer.getvalue()


def _read(path: str | Path) -> tuple[bytes, dict[str, Any]]:
    """(file bytes, driveopt record) of a checked policy file."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise PolicyError(f"cannot read policy {path}: {exc.strerror or exc}") from None
    try:
        with zipfile.ZipFile(io.BytesIO(raw)) as archive:
            bad = archive.testzip()
            if bad is not None:
                raise PolicyError(f"{path} is corrupted (checksum mismatch in {bad})")
            names = archive.namelist()
            if RECORD_ENTRY not in names:
                raise PolicyError(f"{path} is not a driveopt policy (no {RECORD_ENTRY}; write it with `driveopt train dqn|ppo`)")
            record = json.loads(archive.read(RECORD_ENTRY))
    except PolicyError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, ValueError, OSError) as exc:  # ValueError: JSON, CRC
        raise PolicyError(f"{path} is corrupted or not a policy file (truncated or modified: {exc})") from None
    if not isinstance(record, dict) or record.get("format") != FORMAT:
        raise PolicyError(f"{path} is not a driveopt policy (bad {RECORD_ENTRY})")
    if record.get("schema_version") != SCHEMA_VERSION:
        raise PolicyError(f"{path} has policy schema {record.get('schema_version')}; this driveopt reads {SCHEMA_VERSION}")
    return raw, record


def read_record(path: str | Path, algo: str | None = None) -> dict[str, Any]:
    """The driveopt record of the policy file ``path``; with ``algo``, PolicyError when it holds another algorithm."""
    record = _read(path)[1]
    if algo is not None and record.get("algo") != algo:
        raise PolicyError(f"{path} holds a '{record.get('algo')}' policy, expected '{algo}'")
    return record


def load_model(path: str | Path, algo: str, *, lanes: int | None = None, env: Any = None,
               device: str = "cpu") -> tuple[Any, dict[str, Any]]:
    """(Stable-Baselines3 model, record) of the policy file ``path``.

    ``lanes``: PolicyError when the policy was trained on roads with another lane count (as the CVAE's
    weights are checked). ``env``: the (vectorised) env to continue training in.
    """
    check_algo(algo)
    raw, record = _read(path)
    if record.get("algo") != algo:
        raise PolicyError(f"{path} holds a '{record.get('algo')}' policy, expected '{algo}'")
    if lanes is not None and record.get("lanes") not in (None, int(lanes)):
        raise PolicyError(f"{path} was trained on {record.get('lanes')}-lane roads; this road has {lanes} lanes")
    cls = algorithm_class(algo)
    try:
        model = cls.load(io.BytesIO(raw), env=env, device=device)
    except (KeyError, ValueError, RuntimeError, EOFError, zipfile.BadZipFile) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise PolicyError(f"{path} cannot be loaded as a {algo} policy: {reason}") from None
    return model, record


_CACHE: dict[tuple[str, int, int, str], Any] = {}


def cached_policy(path: str | Path, algo: str, lanes: int) -> Any:
    """:func:`load_model` for driving (no env), loaded once per process and file version."""
    path = Path(path)
    try:
        stat = path.stat()
    except OSError as exc:
        raise PolicyError(f"cannot read policy {path}: {exc.strerror or exc}") from None
    key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size, algo)
    if key not in _CACHE:
        model, record = load_model(path, algo, lanes=lanes)
        _CACHE[key] = (model, record)
    model, record = _CACHE[key]
    if lanes is not None and record.get("lanes") not in (None, int(lanes)):
        raise PolicyError(f"{path} was trained on {record.get('lanes')}-lane roads; this road has {lanes} lanes")
    return model


def buffer_sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()
