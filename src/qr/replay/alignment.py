"""When the trajectory started on the log's clock, where, and the controller's mass parameter: found from
the flight (none of them is logged).

``from_thrust``: the controller's thrust law through the firmware's PWM model is linear in ``m`` and ``m o`` for a
given start time (least squares; the start time by a 1-D search).  ``from_position`` (a log without commands):
biased by the tracking lag and the steady error (said so).  The start time's uncertainty is half the
difference between the two halves' start times.  Measured on the IMRCLab flights: docs/replay.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import math

import numba as nb
import numpy as np

from ..linalg_compiled import cholesky_solve

from ..errors import QrInputError
from .lee import GRAVITY
from .setpoints import PiecewisePolynomial, Setpoints

SEARCH_STEP_S = 0.05  # grid of the start-time search (on every SUBSAMPLE-th sample) before the bounded refinement
SUBSAMPLE = 5


@dataclass(frozen=True)
class Alignment:
    """Start time (s, log clock) with its uncertainty, start point (m), controller mass (kg), how found
    (``commands``, ``position``, ``given``, ``synth``), the fit's residual RMS (N or m) and the start times of
    the flight's halves."""

    offset_s: float
    offset_uncertainty_s: float | None
    origin: tuple
    mass: float | None
    source: str
    fit_rms: float | None = None
    fit_unit: str | None = None
    halves_s: tuple | None = None


@nb.njit(cache=True)
def _normal(A, y):
    n, k = A.shape
    N = np.zeros((k, k))
    b = np.zeros((k, 1))
    for r in range(n):
        for i in range(k):
            b[i, 0] += A[r, i] * y[r]
            for j in range(k):
                N[i, j] += A[r, i] * A[r, j]
    return N, b


def lstsq(A, y) -> np.ndarray:
    """Least squares by the normal equations, summed in a fixed order and solved by Cholesky (compiled): the
    same last bits under any BLAS kernel (LAPACK's ``lstsq`` is not); the columns here are a handful of
    well-scaled regressors."""
    A = np.ascontiguousarray(A, float)
    N, b = _normal(A, np.ascontiguousarray(y, float))
    x = np.empty_like(b)
    if not cholesky_solve(N, b, np.zeros_like(N), x):
        return np.linalg.lstsq(A, y, rcond=None)[0]  # rank-deficient: LAPACK's minimum-norm answer
    return x[:, 0]


def minimize_scalar(f, bounds, tol: float = 1e-6) -> float:
    """The minimum of a unimodal ``f`` on ``bounds`` by golden-section search (to ``tol``): the one-dimensional
    search needs nothing more, and importing scipy.optimize costs a user a third of a second."""
    a, b = bounds
    r = (math.sqrt(5.0) - 1.0) / 2.0
    c, d = b - r * (b - a), a + r * (b - a)
    fc, fd = f(c), f(d)
    while b - a > tol:
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - r * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + r * (b - a)
            fd = f(d)
    return 0.5 * (a + b)


def _search(cost, lo: float, hi: float) -> float:
    """The start time minimising ``cost(x, rows)``: a grid on a subsample, then a bounded search on all rows."""
    grid = np.arange(lo, hi + SEARCH_STEP_S / 2, SEARCH_STEP_S)
    values = np.array([cost(x, slice(None, None, SUBSAMPLE)) for x in grid])
    x0 = grid[int(np.argmin(values))]
    return float(minimize_scalar(lambda x: cost(x, slice(None)), (x0 - SEARCH_STEP_S, x0 + SEARCH_STEP_S)))


def _range(t, traj: PiecewisePolynomial, timescale: float) -> tuple[float, float]:
    """Start times for which the trajectory overlaps at least half of the log."""
    span = traj.duration * timescale
    return float(t[0] - span / 2), float(t[-1] - span / 2)


def _thrust_design(t, p, v, R, traj, timescale, offset, gains, mass, origin):
    sp = Setpoints(traj, timescale, offset).at(t, order=2)  # origin at the trajectory's own start point
    Kp, Kd = np.asarray(gains.Kpos_P), np.asarray(gains.Kpos_D)
    F = sp["a"] + Kd * (sp["v"] - v) + Kp * (sp["p"] - p)
    F[:, 2] += GRAVITY
    z = R[:, :, 2]
    cols = [np.einsum("ni,ni->n", F, z)]
    if origin is None:
        cols += [Kp[i] * z[:, i] for i in range(3)]
    else:
        cols[0] = cols[0] + np.einsum("i,ni->n", Kp * np.asarray(origin, float), z)
    return np.stack(cols, axis=1)


def _thrust_fit(t, p, v, R, thrust, traj, timescale, offset, gains, mass, origin):
    A = _thrust_design(t, p, v, R, traj, timescale, offset, gains, mass, origin)
    if mass is not None:  # the mass given: the origin's three columns (or nothing) remain
        y = thrust - mass * A[:, 0]
        if A.shape[1] == 1:
            return float(np.mean(y ** 2)), mass, tuple(origin)
        c = lstsq(mass * A[:, 1:], y)
        r = y - mass * A[:, 1:] @ c
        return float(np.mean(r ** 2)), mass, tuple(float(x) for x in c)
    c = lstsq(A, thrust)
    r = thrust - A @ c
    m = float(c[0])
    o = tuple(origin) if origin is not None else tuple(float(x) / m for x in c[1:])
    return float(np.mean(r ** 2)), m, o


def from_thrust(t, p, v, R, thrust, traj: PiecewisePolynomial, timescale: float, gains, mass=None, origin=None,
                path=None) -> Alignment:
    """The start time, point and mass from the controller's collective ``thrust`` (N) at times ``t`` beside
    the state it saw (``p``, ``v``: (n, 3); ``R``: (n, 3, 3)); ``mass`` / ``origin`` given are kept."""
    ok = np.isfinite(thrust) & np.isfinite(p).all(1) & np.isfinite(v).all(1)
    t, p, v, R, thrust = t[ok], p[ok], v[ok], R[ok], thrust[ok]
    if len(t) < 50:
        raise QrInputError(path, "too few samples with motor commands to find the trajectory's start",
                           "give a longer log, or replay.offset_s=… and replay.origin=[x,y,z]")

    def fit(x, sl=slice(None)):
        return _thrust_fit(t[sl], p[sl], v[sl], R[sl], thrust[sl], traj, timescale, x, gains, mass, origin)

    lo, hi = _range(t, traj, timescale)
    offset = _search(lambda x, sl: fit(x, sl)[0], lo, hi)
    cost, m, o = fit(offset)
    halves = _halves(t, lambda x, sl: fit(x, sl)[0], offset)
    return Alignment(offset, _uncertainty(halves), o, m, "commands", float(np.sqrt(cost)), "N", halves)


def from_position(t, p, traj: PiecewisePolynomial, timescale: float, origin=None, path=None) -> Alignment:
    """The start time and point from the logged position alone (biased: see the module)."""
    ok = np.isfinite(p).all(1)
    t, p = t[ok], p[ok]
    if len(t) < 20:
        raise QrInputError(path, "too few position samples to find the trajectory's start",
                           "give replay.offset_s=… and replay.origin=[x,y,z]")

    def fit(x, sl=slice(None)):
        r = Setpoints(traj, timescale, x).at(t[sl], order=0)["p"]
        o = np.asarray(origin, float) if origin is not None else np.mean(p[sl] - r, axis=0)
        return float(np.mean(np.sum((p[sl] - r - o) ** 2, axis=1))), tuple(float(x) for x in o)

    lo, hi = _range(t, traj, timescale)
    offset = _search(lambda x, sl: fit(x, sl)[0], lo, hi)
    cost, o = fit(offset)
    halves = _halves(t, lambda x, sl: fit(x, sl)[0], offset)
    return Alignment(offset, _uncertainty(halves), o, None, "position", float(np.sqrt(cost)), "m", halves)


def _halves(t, cost, offset: float) -> tuple:
    """The start time each half of the flight gives alone (searched within ±0.5 s of the whole's)."""
    mid = 0.5 * (t[0] + t[-1])
    out = []
    for sl in (slice(0, int(np.searchsorted(t, mid))), slice(int(np.searchsorted(t, mid)), len(t))):
        if sl.stop - sl.start < 20:
            return None
        out.append(float(minimize_scalar(lambda x: cost(x, sl), (offset - 0.5, offset + 0.5))))
    return tuple(out)


def _uncertainty(halves) -> float | None:
    return None if halves is None else 0.5 * abs(halves[0] - halves[1])
