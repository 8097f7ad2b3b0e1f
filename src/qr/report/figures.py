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


def end_to_end(t, group, *values, spacing: float = 0.02):
    """Samples of several flights (or segments) on one time axis, one after another, never joined.

    ``t``: each sample's time in its own flight's clock; ``group``: its flight (or segment), the
    samples of a group together and in time order; ``values``: arrays with a row per sample.  Each
    group after the first is shifted to start ``spacing`` × the total span after the one before;
    a NaN row goes between groups and into every time gap (more than 1.5 steps), so a line plot
    breaks there.  Returns ``(x, [values...], spans)``, ``spans`` the (start, end) of each group on x.
    """
    import numpy as np

    t, group = np.asarray(t, float), np.asarray(group)
    starts = np.flatnonzero(np.r_[True, group[1:] != group[:-1]])
    ends = np.r_[starts[1:], len(t)]
    steps = np.concatenate([np.diff(t[a:b]) for a, b in zip(starts, ends)] or [np.zeros(0)])
    dt = float(np.median(steps)) if steps.size else 0.0
    total = sum(float(t[b - 1] - t[a]) for a, b in zip(starts, ends))
    xs, cols, spans, offset = [], [[] for _ in values], [], 0.0
    for k, (a, b) in enumerate(zip(starts, ends)):
        shift = 0.0 if k == 0 else offset - t[a]
        x = t[a:b] + shift
        cut = np.flatnonzero(np.diff(x) > 1.5 * dt) + 1 if dt > 0 else np.zeros(0, int)
        pieces = np.split(np.arange(a, b), cut)
        for piece in pieces:
            xs.append(np.r_[t[piece] + shift, np.nan])
            for c, v in zip(cols, values):
                v = np.asarray(v, float)
                c.append(np.vstack([v[piece], np.full((1,) + v.shape[1:], np.nan)]))
        spans.append((float(x[0]), float(x[-1])))
        offset = x[-1] + spacing * total
    return np.concatenate(xs), [np.concatenate(c) for c in cols], spans
