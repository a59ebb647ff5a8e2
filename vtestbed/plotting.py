"""Figures: one matplotlib setup (no screen needed) and one way to save and close a figure.

matplotlib is imported only when a figure is drawn, so importing a module that can plot costs
nothing when no figure is asked for.
"""

from __future__ import annotations

from pathlib import Path


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (files only, no display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: str | Path, dpi: int = 110, tight: bool = True, rect=None) -> Path:
    """Lay out (unless ``tight`` is False), save ``fig`` as ``path`` and close it; returns the path."""
    if tight:
        fig.tight_layout(**({} if rect is None else {"rect": rect}))
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    pyplot().close(fig)
    return path
