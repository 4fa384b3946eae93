"""Output folders of the long jobs (bench, summarise, the trainers): one check and one creation, with one-line errors."""

from __future__ import annotations

from pathlib import Path


def check_output_folder(out: str | Path, error: type[Exception], holds: str) -> Path:
    """``out`` as a Path; ``error`` when it is an existing file (the job writes ``holds`` there)."""
    path = Path(out)
    if path.exists() and not path.is_dir():
        raise error(f"the output folder {path} is an existing file; give a folder (for {holds})")
    return path


def make_output_folder(out: str | Path, error: type[Exception], holds: str) -> Path:
    """Create ``out`` (and its parents) after :func:`check_output_folder`; ``error`` when it cannot be created."""
    path = check_output_folder(out, error, holds)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise error(f"cannot create the output folder {path}: {exc.strerror or exc}") from None
    return path
