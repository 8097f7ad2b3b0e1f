"""Figure helpers: headless backend, one style, atomic PNG writes."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from ..atomic import atomic_path  # noqa: E402

plt.rcParams.update({"figure.dpi": 110, "axes.grid": True, "grid.alpha": 0.3, "font.size": 9})


def save(fig, path: str | Path, tight: bool = True) -> None:
    """``tight=False`` for many-panel figures laid out by hand: a tight bounding box draws them twice."""
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", bbox_inches="tight" if tight else None)
    plt.close(fig)


def subplots(*args, grid: bool = True, **kwargs):
    with plt.rc_context({"axes.grid": grid}):
        return plt.subplots(*args, **kwargs)
