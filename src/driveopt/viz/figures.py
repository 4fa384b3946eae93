"""Figures written whole: the formats a figure path may name, and saving a matplotlib figure through a renamed
temporary file (:func:`driveopt.files.atomic_output`), so a failed save leaves no half-written figure."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from driveopt.files import atomic_output


def figure_suffixes() -> tuple[str, ...]:
    """The file extensions matplotlib can save a figure as (``.png``, ``.pdf``, ``.svg``, ...), lower case with the dot:
    the format is chosen by the extension, so any other one is refused before the figure is drawn."""
    from matplotlib.backend_bases import FigureCanvasBase

    return tuple(sorted(f".{suffix}" for suffix in FigureCanvasBase.get_supported_filetypes()))


def save_figure(fig: Any, path: str | Path, dpi: int = 110) -> Path:
    """Lay out, write (format by extension, parent folders created) whole, and close ``fig``; OutputError when the
    write fails."""
    import matplotlib.pyplot as plt

    path = Path(path)
    try:
        fig.tight_layout()
        with atomic_output(path) as tmp:
            fig.savefig(tmp, dpi=dpi)
    finally:
        plt.close(fig)
    return path
