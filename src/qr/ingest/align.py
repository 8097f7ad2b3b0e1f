"""Time offset between the motion-capture stream and the on-board gyro, estimated from the physics.

Motion capture and the autopilot stamp on different clocks (and an on-board log often stamps a sample
when it is written, not when it was measured). The gyro measures the body rate the motion-capture
attitude implies (``2 vec(q_k⁻¹ ⊗ q_k+1) / dt``), with no force model in between: the offset is the lag
of the peak of their normalised cross-correlation (both low-passed alike, means removed), refined to a
fraction of a sample by a parabola through the peak. ``aligned(t) = logged(t + τ)`` (positive: the gyro
was stamped late).

Not done: the rotor stream. Its coupling, the thrust against the vertical force the mocap trajectory
needs, is confounded with drag (a force along the velocity leads the acceleration): on synthetic
flights with drag the peak sat 70-110 ms from the truth, and fitting the drag share beside the thrust
absorbed most of a real offset. A rotor offset is left to the diagnosis (``actuator_delay``).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.signal import savgol_filter

from ..estimation.savgol import uniform_grid, window
from ..flight import GYRO
from ..frames import quat_multiply

MAX_LAG_S = 0.5
SMOOTH_S = 0.15  # the low-pass both signals share (Savitzky-Golay window, s)
MAX_SAMPLES = 30000  # a longer log is aligned on its middle


def _fill(t, y):
    ok = np.isfinite(y)
    return np.interp(t, t[ok], y[ok]) if ok.sum() >= 2 else np.full_like(t, np.nan)


def _lag(t, stream, reference, max_lag_s, smooth_s=SMOOTH_S, max_samples=MAX_SAMPLES):
    """(τ, peak correlation): ``stream(t + τ)`` best matches ``reference(t)`` (both (N, k), summed over k)."""
    grid = uniform_grid(t)
    dt = grid[1] - grid[0]
    n = int(round(max_lag_s / dt))
    a = np.column_stack([np.interp(grid, t, _fill(t, c)) for c in np.atleast_2d(np.asarray(stream).T)])
    b = np.column_stack([np.interp(grid, t, _fill(t, c)) for c in np.atleast_2d(np.asarray(reference).T)])
    # the same zero-phase low-pass on both (no lag of its own): above a few Hz the mocap derivatives are
    # noise, which would make the peak wander by more than a sample
    win = window(grid, smooth_s)
    a, b = savgol_filter(a, win, 3, axis=0), savgol_filter(b, win, 3, axis=0)
    m = len(grid)
    if m - 2 * n > max_samples:  # a constant offset: the middle of a long log says it
        mid = slice((m - max_samples) // 2 - n, (m + max_samples) // 2 + n)
        a, b, m = a[mid], b[mid], max_samples + 2 * n
    a, b = a - a.mean(axis=0), b - b.mean(axis=0)
    lags = np.arange(-n, n + 1)
    corr = np.empty(len(lags))
    for i, k in enumerate(lags):  # stream shifted by k samples: a[j + k] against b[j]
        lo, hi = max(0, -k), min(m, m - k)
        x, y = a[lo + k:hi + k], b[lo:hi]
        corr[i] = float(np.sum(x * y) / np.sqrt(np.sum(x * x) * np.sum(y * y)))
    i = int(np.argmax(corr))
    frac = 0.0
    if 0 < i < len(lags) - 1:
        c0, c1, c2 = corr[i - 1], corr[i], corr[i + 1]
        den = c0 - 2 * c1 + c2
        frac = 0.5 * (c0 - c2) / den if den < 0 else 0.0
    return float((lags[i] + frac) * dt), float(corr[i])


def offsets(flight: pd.DataFrame, max_lag_s: float = MAX_LAG_S) -> dict:
    """``{"gyro": {"offset_s", "correlation", "against"}}``; empty where the log has no gyro."""
    if not all(col in flight for col in GYRO):
        return {}
    t = flight["t"].to_numpy(float)
    q = flight[["qw", "qx", "qy", "qz"]].to_numpy(float)
    if np.all(np.isfinite(q), axis=1).sum() <= 10 or np.all(np.isfinite(flight[GYRO].to_numpy(float)), axis=1).sum() <= 10:
        return {}
    q = np.column_stack([_fill(t, c) for c in q.T])
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    dq = quat_multiply(q[:-1] * np.array([1.0, -1, -1, -1]), q[1:])
    w = 2 * np.sign(dq[:, :1]) * dq[:, 1:] / np.diff(t)[:, None]  # body rate between samples, at the midpoints
    w_mid = np.column_stack([np.interp(t, 0.5 * (t[1:] + t[:-1]), c) for c in w.T])
    tau, c = _lag(t, flight[GYRO].to_numpy(float), w_mid, max_lag_s)
    return {"gyro": {"offset_s": tau, "correlation": c, "against": "gyro vs the mocap attitude's rate"}}


def apply(flight: pd.DataFrame, found: dict) -> pd.DataFrame:
    """The flight with the gyro moved by its offset (``aligned(t) = logged(t + τ)``; NaN where the
    shifted stream has no sample)."""
    out = flight.copy()
    t = flight["t"].to_numpy(float)
    for kind, cols in (("gyro", GYRO),):
        if kind not in found:
            continue
        tau = found[kind]["offset_s"]
        for col in cols:
            y = flight[col].to_numpy(float)
            ok = np.isfinite(y)
            out[col] = np.interp(t + tau, t[ok], y[ok], left=np.nan, right=np.nan)
    return out
