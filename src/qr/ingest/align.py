"""Time offsets between the motion-capture stream and the on-board streams, estimated from the physics.

Each on-board stream (gyro; rotors, through the roll and pitch torque channel) is compared with what the
motion-capture trajectory says it should have been, and the offset is the lag at which they agree best:
``aligned(t) = logged(t + τ)`` (positive: the stream was stamped late).  The channels, why the torque and not
the thrust, and the limits: docs/ingest.md "Time offsets between the streams".
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.signal import savgol_filter

from ..estimation.savgol import uniform_grid, window
from ..flight import GYRO, ROTORS
from ..frames import quat_multiply, quat_to_rot, to_body

MAX_LAG_S = 0.5
SMOOTH_S = 0.15  # the low-pass every signal shares (Savitzky-Golay window, s)
MAX_SAMPLES = 30000  # a longer log is aligned on its middle
STREAMS = {"gyro": GYRO, "rotors": ROTORS}


def _fill(t, y):
    ok = np.isfinite(y)
    return np.interp(t, t[ok], y[ok]) if ok.sum() >= 2 else np.full_like(t, np.nan)


def _on_grid(t, grid, y):
    return np.column_stack([np.interp(grid, t, _fill(t, c)) for c in np.asarray(y, float).reshape(len(t), -1).T])


def _lag(t, stream, reference, max_lag_s, confounders=None, smooth_s=SMOOTH_S, max_samples=MAX_SAMPLES):
    """(τ, peak correlation): ``stream(t + τ)`` best matches ``reference(t)`` (both (N, k), summed over k);
    None for a log too short for the lag window.

    ``confounders`` (N, k, p): signals fitted beside the stream in column j of the reference at every
    lag (a constant always is), so the correlation is a partial one."""
    grid = uniform_grid(t)
    dt = grid[1] - grid[0]
    n = int(round(max_lag_s / dt))
    a, b = _on_grid(t, grid, stream), _on_grid(t, grid, reference)
    k = b.shape[1]
    z = np.zeros((len(t), k, 0)) if confounders is None else np.asarray(confounders, float)
    p = z.shape[2]
    z = _on_grid(t, grid, z.reshape(len(t), -1)).reshape(len(grid), k, p) if p else np.zeros((len(grid), k, 0))
    # the same zero-phase low-pass on all (no lag of its own): above a few Hz the mocap derivatives are
    # noise, which would make the peak wander by more than a sample
    win = window(grid, smooth_s)
    a, b = savgol_filter(a, win, 3, axis=0), savgol_filter(b, win, 3, axis=0)
    if p:
        z = savgol_filter(z, win, 3, axis=0)
    m = len(grid)
    if m - 2 * n > max_samples:  # a constant offset: the middle of a long log says it
        mid = slice((m - max_samples) // 2 - n, (m + max_samples) // 2 + n)
        a, b, z, m = a[mid], b[mid], z[mid], max_samples + 2 * n
    if m - 2 * n < max(50, 5 * (p + 1)):  # too short a log for this lag window: nothing to say
        return None
    inner = slice(n, m - n)  # the reference's samples every lag reaches
    bases, y = [], np.empty((m - 2 * n, k))
    for j in range(k):
        basis = np.linalg.qr(np.column_stack([np.ones(m - 2 * n), z[inner, j]]))[0]
        bases.append(basis)
        y[:, j] = b[inner, j] - basis @ (basis.T @ b[inner, j])
    lags = np.arange(-n, n + 1)
    corr = np.empty(len(lags))
    yy = float(np.sum(y * y))
    for i, s in enumerate(lags):  # stream shifted by s samples: a[j + s] against b[j]
        x = a[n + s:m - n + s]
        x = np.column_stack([x[:, j] - bases[j] @ (bases[j].T @ x[:, j]) for j in range(k)])
        xx = float(np.sum(x * x))
        # a stream that never varies (rotors that never ran) has no correlation: nothing to say
        corr[i] = float(np.sum(x * y)) / np.sqrt(xx * yy) if xx * yy > 0 else np.nan
    if not np.isfinite(corr).all():
        return None
    return _peak(corr, lags, dt)


def _peak(corr, lags, dt):
    """(lag of the correlation's peak in s, refined by a parabola through it; the peak correlation)."""
    i = int(np.argmax(corr))
    frac = 0.0
    if 0 < i < len(lags) - 1:
        c0, c1, c2 = corr[i - 1], corr[i], corr[i + 1]
        den = c0 - 2 * c1 + c2
        frac = 0.5 * (c0 - c2) / den if den < 0 else 0.0
    return float((lags[i] + frac) * dt), float(corr[i])


def _body_rate(t, q):
    """Body rate (N, 3) the attitude implies: between samples, interpolated back onto the samples."""
    dq = quat_multiply(q[:-1] * np.array([1.0, -1, -1, -1]), q[1:])
    w = 2 * np.sign(dq[:, :1]) * dq[:, 1:] / np.diff(t)[:, None]
    return np.column_stack([np.interp(t, 0.5 * (t[1:] + t[:-1]), c) for c in w.T])


def _rotor_lag(flight, t, q, w, vehicle, max_lag_s):
    u = flight[ROTORS].to_numpy(float)
    if np.all(np.isfinite(u), axis=1).sum() <= 10:
        return None
    J = np.asarray(vehicle.inertia, float)
    wrench = vehicle.rotors.wrench(np.column_stack([_fill(t, c) for c in u.T]))
    commanded = wrench[:, 1:3] / J[:2]
    alpha = np.gradient(w, t, axis=0)
    needed = (alpha * J + np.cross(w, w * J))[:, :2] / J[:2]
    p = np.column_stack([_fill(t, flight[c].to_numpy(float)) for c in ("px", "py", "pz")])
    v_b = to_body(quat_to_rot(q), np.gradient(p, t, axis=0))
    thrust = wrench[:, 0]
    confounders = np.stack([np.column_stack([w[:, 0], v_b[:, 1], thrust]),
                            np.column_stack([w[:, 1], v_b[:, 0], thrust])], axis=1)
    found = _lag(t, commanded, needed, max_lag_s, confounders)
    if found is None:
        return None
    tau, c = found
    return {"offset_s": tau, "correlation": c,
            "against": "roll/pitch rotor torque vs the mocap attitude's angular acceleration"}


# An offset is acted on (``--align``) only where the log's two halves, each estimated alone, agree with
# each other to this (s) or to this share of the offset, whichever is larger: a peak that wanders between
# halves is the excitation's, not the clock's (on a gentle, correctly stamped synthetic flight the rotor
# stream's peak sat 34 ms from zero).
AGREE_S = 0.005
AGREE_SHARE = 0.25


def offsets(flight: pd.DataFrame, vehicle=None, max_lag_s: float = MAX_LAG_S) -> dict:
    """``{stream: {"offset_s", "correlation", "against", "halves", "confident"}}`` for ``gyro`` (where the
    log has one) and ``rotors`` (with ``vehicle``); ``halves``: the offset of each half of the log alone,
    ``confident``: whether they agree (``AGREE_S``, ``AGREE_SHARE``) and say to act on it."""
    found = _offsets(flight, vehicle, max_lag_s)
    mid = len(flight) // 2
    parts = [_offsets(flight.iloc[:mid].reset_index(drop=True), vehicle, max_lag_s),
             _offsets(flight.iloc[mid:].reset_index(drop=True), vehicle, max_lag_s)]
    for kind, o in found.items():
        halves = [p.get(kind, {}).get("offset_s") for p in parts]
        o["halves"] = halves
        o["confident"] = None not in halves and abs(halves[0] - halves[1]) <= max(AGREE_S, AGREE_SHARE * abs(o["offset_s"]))
    return found


def _offsets(flight: pd.DataFrame, vehicle=None, max_lag_s: float = MAX_LAG_S) -> dict:
    t = flight["t"].to_numpy(float)
    q = flight[["qw", "qx", "qy", "qz"]].to_numpy(float)
    if np.all(np.isfinite(q), axis=1).sum() <= 10:
        return {}
    q = np.column_stack([_fill(t, c) for c in q.T])
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w = _body_rate(t, q)
    found = {}
    if all(col in flight for col in GYRO) and np.all(np.isfinite(flight[GYRO].to_numpy(float)), axis=1).sum() > 10:
        lag = _lag(t, flight[GYRO].to_numpy(float), w, max_lag_s)
        if lag is not None:
            found["gyro"] = {"offset_s": lag[0], "correlation": lag[1], "against": "gyro vs the mocap attitude's rate"}
    if vehicle is not None and all(col in flight for col in ROTORS):
        rotors = _rotor_lag(flight, t, q, w, vehicle, max_lag_s)
        if rotors is not None:
            found["rotors"] = rotors
    return found


def apply(flight: pd.DataFrame, found: dict) -> pd.DataFrame:
    """The flight with each stream moved by its offset (``aligned(t) = logged(t + τ)``; NaN where the
    shifted stream has no sample); a stream whose offset is not ``confident`` stays."""
    out = flight.copy()
    t = flight["t"].to_numpy(float)
    for kind, cols in STREAMS.items():
        if kind not in found or not found[kind].get("confident", True):
            continue
        tau = found[kind]["offset_s"]
        for col in cols:
            y = flight[col].to_numpy(float)
            ok = np.isfinite(y)
            out[col] = np.interp(t + tau, t[ok], y[ok], left=np.nan, right=np.nan)
    return out
