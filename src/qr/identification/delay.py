"""Actuator delay: the rotor map acting ``d`` late, fitted by its exact form ``W(u(t - d)) - W(u(t))``
(the catalog's first-order ``-d dW/dt`` is poor at tens of ms): a first delay ``d₀`` by a 1-D search and
a secant column for the selection (:func:`estimate`, :func:`secant_column`), the rotor-map effects' designs
read ``d`` late (:func:`shift`), and the bootstrap's linearisation (:func:`tangent_column`).  Why: docs/diagnose.md
"How it decides".
"""

from __future__ import annotations

import numpy as np

from ..parallel import thread_map


def runs(t: np.ndarray, flight: np.ndarray) -> list[tuple[int, int]]:
    """Contiguous runs of increasing time within one flight (the cross-fitting halves repeat time)."""
    starts = np.flatnonzero(np.concatenate([[True], (np.diff(t) <= 0) | (np.diff(flight) != 0)]))
    return list(zip(starts, list(starts[1:]) + [len(t)]))


def shift(t, flight, x: np.ndarray, d: float, rows: np.ndarray | None = None) -> np.ndarray:
    """``x(t - d)`` column by column, by linear interpolation within each run (held at a run's start);
    ``rows`` (sorted indices): only there (the data of the whole run still interpolated)."""
    if rows is None:
        rows = np.arange(len(t))
    if d == 0:
        return x[rows].copy()
    out = np.empty((len(rows), x.shape[1]))
    for a, b in runs(t, flight):
        i, j = np.searchsorted(rows, a), np.searchsorted(rows, b)
        if i == j:
            continue
        tt, at = t[a:b], t[rows[i:j]] - d
        for k in range(x.shape[1]):
            out[i:j, k] = np.interp(at, tt, x[a:b, k])
    return out


def exact_term(t, flight, u2f, u2t, B, d: float, rows: np.ndarray | None = None) -> np.ndarray:
    """Residual of a rotor map acting ``d`` late: ``W(u(t - d)) - W(u(t))`` on f_z and τ (N, 6), or on
    ``rows`` only.  The map is linear in u², so the wrench is shifted (4 columns, not 8 squared speeds)."""
    n = len(t) if rows is None else len(rows)
    term = np.zeros((n, 6))
    if d == 0:
        return term
    W = np.column_stack([u2f @ B[0], u2t @ B[1:].T])  # f_z, τx, τy, τz
    term[:, 2:] = shift(t, flight, W, d, rows) - (W if rows is None else W[rows])
    return term


def secant_column(t, flight, u2f, u2t, B, d0: float) -> np.ndarray:
    """``W(d₀) / d₀``: a design column, in seconds of delay, exact at 0 and at ``d₀``."""
    return exact_term(t, flight, u2f, u2t, B, d0) / d0


def tangent_column(t, flight, u2f, u2t, B, d: float, step: float) -> np.ndarray:
    """``dW/dd`` at ``d`` (central difference of half-width ``step``; one-sided at 0)."""
    lo = max(d - step, 0.0)
    return (exact_term(t, flight, u2f, u2t, B, d + step) - exact_term(t, flight, u2f, u2t, B, lo)) / (d + step - lo)


def estimate(loss, d_max: float, d_min: float, n_grid: int = 21) -> float:
    """The delay in ``[d_min, d_max]`` minimising ``loss(d)``: a grid (the loss of a periodic signal has
    several minima), then bounded Brent around the best grid point."""
    from scipy.optimize import minimize_scalar

    xs = np.linspace(d_min, d_max, n_grid)
    vals = thread_map(loss, xs)  # independent evaluations, side by side
    i = int(np.argmin(vals))
    lo, hi = xs[max(i - 1, 0)], xs[min(i + 1, n_grid - 1)]
    res = minimize_scalar(loss, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4})
    return float(res.x) if res.fun <= vals[i] else float(xs[i])
