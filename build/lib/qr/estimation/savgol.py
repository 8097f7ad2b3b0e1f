"""Savitzky-Golay derivatives: a quick, filter-free look at a flight (used by the ingest summary).

Irregular stamps are resampled to the median step, gaps (dropouts) bridged
linearly, and the derivatives mapped back to the original stamps.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import savgol_filter


def uniform_grid(t: np.ndarray) -> np.ndarray:
    dt = float(np.median(np.diff(t)))
    return np.arange(t[0], t[-1] + 0.5 * dt, dt)


def _fill(t, y):
    ok = np.isfinite(y)
    return np.interp(t, t[ok], y[ok])


def window(grid: np.ndarray, window_s: float = 0.21, poly: int = 3) -> int:
    """Samples in the Savitzky-Golay window (odd, at least ``poly + 2``) on a uniform ``grid``."""
    return max(poly + 2, int(round(window_s / (grid[1] - grid[0]))) | 1)


def derivatives(t: np.ndarray, y: np.ndarray, order: int, window_s: float = 0.21, poly: int = 3) -> np.ndarray:
    """``order``-th time derivative of each column of ``y`` (N, k) at stamps ``t``."""
    y = np.asarray(y, dtype=float).reshape(len(t), -1)
    grid = uniform_grid(t)
    dt = grid[1] - grid[0]
    win = window(grid, window_s, poly)
    out = np.empty_like(y)
    for j in range(y.shape[1]):
        yg = np.interp(grid, t, _fill(t, y[:, j]))
        d = savgol_filter(yg, win, poly, deriv=order, delta=dt, mode="interp")
        out[:, j] = np.interp(t, grid, d)
    return out
