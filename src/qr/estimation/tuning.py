"""``filter=auto``: noise intensities that maximise the innovation likelihood of the flight itself.

The gains depend only on ``q / r``, so the scale is profiled out in closed form (``c = mean NIS / m``) and the
ratio is a 1-D search over the filter's corner frequency ``f_c = λ^(1/2m) / 2π`` (log grid from
``tune.min_corner_hz`` to Nyquist, then bounded Brent); ``r₀`` from third differences
(``var Δ³y = 20 σ²``), a second round from the first's ``r``; the first ``nis.burn_in_s`` s left out.
docs/filter.md.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize_scalar

from ..parallel import thread_map
from . import attitude_eskf, motor_kf, position_kf
from .nis import Innovations

ORDER = {"position": 4, "attitude": 4, "motor": 3}


def corner_hz(q: float, r: float, m: int) -> float:
    return (q / r) ** (1 / (2 * m)) / (2 * math.pi)


def robust_noise(y: np.ndarray) -> float:
    """Measurement variance from third differences (MAD, per column, averaged)."""
    d3 = np.diff(np.asarray(y, dtype=float).reshape(len(y), -1), n=3, axis=0)
    out = []
    for col in d3.T:
        col = col[np.isfinite(col)]
        if col.size:
            out.append((1.4826 * np.median(np.abs(col - np.median(col)))) ** 2 / 20)
    v = float(np.mean(out)) if out else 0.0
    return v if v > 0 else 1e-12


def _run(kind: str, t, meas, q, r, speed_scale, reset_deg) -> Innovations:
    if kind == "position":
        return position_kf.filter_fast(t, meas, q, r, "exact")[2]
    if kind == "attitude":
        return attitude_eskf.filter_fast(t, meas, q, r, "exact", reset_deg=reset_deg)[4]
    return motor_kf.filter_fast(t, meas, q, r, "exact", speed_scale=speed_scale)[2]


def _profile(inn: Innovations, keep: np.ndarray):
    ok = np.isfinite(inn.nis) & keep[:, None]
    n = int(ok.sum())
    c = float(np.sum(inn.nis[ok])) / (n * inn.dof)
    ll = -0.5 * (n * inn.dof * (1 + math.log(c) + math.log(2 * math.pi)) + float(np.sum(inn.logdet[ok])))
    return ll, c


def tune(kind: str, t, meas, keep, min_corner_hz=0.05, grid=13, rounds=2, speed_scale=None,
         reset_deg=attitude_eskf.RESET_DEG) -> dict:
    """Maximum-likelihood ``q`` and ``r`` of one filter (``exact`` discretisation)."""
    m = ORDER[kind]
    if kind == "attitude":
        r0 = 16 / 3 * robust_noise(meas)  # |δq|² = |δθ|²/4 = 3σ²/4, over 4 components
    else:
        r0 = robust_noise(meas)
    f_hi = 0.5 / float(np.median(np.diff(t)))
    f_lo = min(float(min_corner_hz), f_hi / 10)
    evals = 0
    for _ in range(rounds):
        cache = {}

        def run(logf, r0=r0):
            lam = (2 * math.pi * math.exp(logf)) ** (2 * m)
            ll, c = _profile(_run(kind, t, meas, lam * r0, r0, speed_scale, reset_deg), keep)
            return ll, c, lam

        def neg(logf, cache=cache):
            if logf not in cache:
                cache[logf] = run(logf)
            return -cache[logf][0]

        xs = np.linspace(math.log(f_lo), math.log(f_hi), grid)
        cache.update(zip(xs, thread_map(run, xs)))  # the grid's filters side by side, kept in grid order
        vals = [neg(x) for x in xs]
        i = int(np.argmin(vals))
        lo, hi = xs[max(i - 1, 0)], xs[min(i + 1, grid - 1)]
        minimize_scalar(neg, bounds=(lo, hi), method="bounded", options={"xatol": 1e-3})
        best = min(cache, key=lambda x: -cache[x][0])
        ll, c, lam = cache[best]
        evals += len(cache)
        r0 = c * r0
        q = lam * r0
    return {"q": float(q), "r": float(r0), "corner_hz": corner_hz(q, r0, m), "log_likelihood": float(ll),
            "at_bound": bool(abs(best - math.log(f_lo)) < 1e-6 or abs(best - math.log(f_hi)) < 1e-6),
            "evaluations": evals}
