"""Files shipped inside the package: the weights in ``driveopt/weights`` (CVAE, VQ-VAE + PixelCNN, safety filter,
RL policies), looked up by file name for a road's lane count."""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def shipped_weights_file(by_lanes: dict[int, str], lanes: int) -> Path | None:
    """The file that ``by_lanes`` names for roads with ``lanes`` lanes in ``driveopt/weights``, or None when it names
    none or the file does not ship."""
    name = by_lanes.get(int(lanes))
    if name is None:
        return None
    path = Path(str(resources.files("driveopt") / "weights" / name))
    return path if path.is_file() else None
