"""Open-loop replay: how far does a model drift from the measured flight?

The model is restarted from the filtered state every ``horizon_s`` and driven
by the measured (filtered) rotor speeds; its predicted positions and attitudes
are compared with the motion-capture measurements.  The extended model is the
same TRUE plant ``qr synth`` flies (``qr.sim.plant``), with the named effects
as its physics, so a replay and a synthetic flight never disagree on what an
effect means.  The diagnosis also rolls the models out from every held-out
start (:func:`rollout_all`, the field's yardstick: :mod:`qr.rollout`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numba as nb
import numpy as np
import pandas as pd

from .. import rollout
from ..flight import on_stamps
from ..frames import quat_to_rot
from ..parallel import thread_map
from ..plant_state import N_RB, P_DELAY, P_MARKER, X_QUAT, X_VEL
from ..sim.plant import cg_from_tracked, rigid_body_rk4, tracked_pv, true_params
from ..states import POSITION, QUATERNION, RATE, ROTORS, VELOCITY
from .held_out import Explained
from .labels import flight_of


@dataclass(frozen=True)
class Drift:
    """A replay's error at the horizon (the last sample of each full window): position RMSE per axis and
    overall (m), attitude RMSE (deg), over ``windows`` windows (none: no number)."""

    windows: int
    position_rmse_axes: tuple[float, ...] = ()
    position_rmse: float = float("nan")
    attitude_rmse_deg: float = float("nan")


@dataclass(frozen=True)
class ModelReplay:
    """One model's replay: the per-sample errors (:func:`replay`), their :class:`Drift` and their growth."""

    errors: pd.DataFrame
    summary: Drift
    growth: pd.DataFrame


@dataclass(frozen=True)
class Replays:
    """The open-loop replay of the nominal and of the extended model."""

    nominal: ModelReplay
    extended: ModelReplay


@dataclass(frozen=True)
class HeldOutRollout:
    """The multi-step rollout from the held-out starts (``diagnosis.json``'s ``rollout``): per model the spec's
    block (:func:`qr.rollout.summary`, keyed by quantity), and the share of the residual the named effects
    explain."""

    horizon: int
    models: Mapping[str, rollout.RolloutBlock]  # model -> its block (qr.rollout.summary)
    explained: Explained
    part: str = "held-out"
    dt: float | None = None  # s, the flights' median step (h steps are h dt seconds, as evaluation.json's "dt")

    def record(self) -> dict:
        return {"horizon": self.horizon, "dt": self.dt, "part": self.part, "models": dict(self.models),
                "explained": self.explained.record()}


@nb.njit(cache=True)
def _speeds_at(t, tt, U, k, out):
    """Rotor speeds at time ``t`` into ``out``, by linear interpolation around index ``k``; the new ``k``."""
    n = tt.shape[0]
    while k > 0 and tt[k] > t:
        k -= 1
    while k < n - 2 and tt[k + 1] < t:
        k += 1
    if t <= tt[0]:
        out[:] = U[0]
    elif t >= tt[n - 1]:
        out[:] = U[n - 1]
    else:
        f = (t - tt[k]) / (tt[k + 1] - tt[k])
        for m in range(out.shape[0]):
            out[m] = (1 - f) * U[k, m] + f * U[k + 1, m]
    return k


@nb.njit(cache=True, nogil=True)
def _replay(t, X0, U, starts, horizon, P, substeps):
    """Predicted tracked-point position and attitude at every sample of every window."""
    n = t.shape[0]
    pos = np.full((n, 3), np.nan)
    quat = np.full((n, 4), np.nan)
    elapsed = np.full(n, np.nan)
    r = P[P_MARKER].copy()
    zero = np.zeros(3)
    d = P[P_DELAY]
    m = U.shape[1]
    u0, um, u1 = np.empty(m), np.empty(m), np.empty(m)
    x, xn, xs, kk = np.empty(N_RB), np.empty(N_RB), np.empty(N_RB), np.empty((4, N_RB))
    v = X_VEL.start
    for s in range(starts.shape[0]):
        i0 = starts[s]
        x[:] = X0[i0]
        cg_from_tracked(x, r)
        k = i0
        i = i0
        while True:
            pos[i, 0], pos[i, 1], pos[i, 2], _, _, _ = tracked_pv(x, r)
            quat[i] = x[X_QUAT]
            elapsed[i] = t[i] - t[i0]
            if i + 1 >= n or t[i + 1] - t[i0] > horizon + 1e-9:
                break
            h = (t[i + 1] - t[i]) / substeps
            for j in range(substeps):
                tj = t[i] + j * h
                k = _speeds_at(tj - d, t, U, k, u0)
                k = _speeds_at(tj + 0.5 * h - d, t, U, k, um)
                k = _speeds_at(tj + h - d, t, U, k, u1)
                rigid_body_rk4(x, u0, um, u1, P, h, False, zero, kk, xs, xn)
                x, xn = xn, x
            i += 1
            if not (np.all(np.isfinite(x)) and abs(x[v]) + abs(x[v + 1]) + abs(x[v + 2]) < 1e3):
                break  # the model diverged in this window: stop predicting
    return pos, quat, elapsed


def replay(states: pd.DataFrame, measured: pd.DataFrame, vehicle, effects: list[dict], horizon_s: float,
           substeps: int = 2) -> pd.DataFrame:
    """Per-sample replay errors: position (m, world) and attitude (rad) against the measurement."""
    t = states["t"].to_numpy()
    X0 = np.hstack([states[POSITION + VELOCITY + QUATERNION + RATE].to_numpy()])
    U = states[ROTORS].to_numpy()
    P = true_params(vehicle, effects)
    starts = _window_starts(t, horizon_s)
    pos, quat, elapsed = _replay(t, X0, U, starts, float(horizon_s), P, substeps)
    meas_p = measured[POSITION].to_numpy()
    meas_q = measured[QUATERNION].to_numpy()
    err = pos - meas_p
    ok = np.isfinite(quat).all(axis=1) & np.isfinite(meas_q).all(axis=1)
    ok[ok] = np.linalg.norm(quat[ok], axis=1) > 0.5
    att = np.full(len(t), np.nan)
    if ok.any():
        Rp, Rm = quat_to_rot(quat[ok]), quat_to_rot(meas_q[ok])
        rel = np.einsum("nji,njk->nik", Rm, Rp)
        att[ok] = np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1))
    window = np.searchsorted(starts, np.arange(len(t)), side="right") - 1
    return pd.DataFrame({"t": t, "window": window, "elapsed": elapsed, "ex": err[:, 0], "ey": err[:, 1],
                         "ez": err[:, 2], "attitude_error": att})


def _window_starts(t: np.ndarray, horizon_s: float) -> np.ndarray:
    starts, nxt = [], t[0]
    for i, ti in enumerate(t):
        if ti >= nxt - 1e-9:
            starts.append(i)
            nxt = ti + horizon_s
    return np.array(starts, dtype=np.int64)


def summarise(err: pd.DataFrame, horizon_s: float, mask=None) -> Drift:
    """RMSE at the horizon (last sample of each full window), per axis and overall, and attitude."""
    e = err if mask is None else err[mask]
    last = e.groupby("window").tail(1)
    last = last[last["elapsed"] > 0.8 * horizon_s]
    xyz = last[["ex", "ey", "ez"]].to_numpy()
    ok = np.isfinite(xyz).all(axis=1)
    xyz = xyz[ok]
    if len(xyz) == 0:
        return Drift(0)
    return Drift(int(len(xyz)), tuple(np.sqrt((xyz**2).mean(axis=0)).tolist()),
                 float(np.sqrt((xyz**2).sum(axis=1).mean())),
                 float(np.degrees(np.sqrt(np.nanmean(last["attitude_error"].to_numpy()[ok] ** 2)))))


def growth(err: pd.DataFrame, horizon_s: float, bins: int = 20) -> pd.DataFrame:
    """RMS position error per axis against time since the restart."""
    edges = np.linspace(0, horizon_s, bins + 1)
    b = np.clip(np.digitize(err["elapsed"], edges) - 1, 0, bins - 1)
    g = err.assign(bin=b).groupby("bin")[["ex", "ey", "ez"]].apply(lambda d: np.sqrt((d**2).mean()))
    g.insert(0, "elapsed", (edges[:-1] + edges[1:])[g.index] / 2)
    return g.reset_index(drop=True)


def replay_all(states_list, measured_list, vehicle, extension: list[dict], horizon_s: float,
               windows: list[dict]) -> Replays:
    """Replay each state table (a flight or a gap-free segment of one) on its own measured rows, with the
    vehicle's own effects (``nominal``) and with ``extension`` added (``extended``): per model the errors,
    their summary at the horizon and their growth, over the windows that start in each flight's held-out
    part (``windows``: per flight, its train/test windows)."""
    out = {"nominal": [], "extended": []}
    owner = flight_of(states_list)
    for i, (st, meas) in enumerate(zip(states_list, measured_list)):
        meas = on_stamps(meas, st["t"])
        models = (("nominal", vehicle.effects), ("extended", vehicle.effects + extension))
        errs = thread_map(lambda m: replay(st, meas, vehicle, m[1], horizon_s), models)
        for (key, _), err in zip(models, errs):
            out[key].append(err.assign(test=err["t"] >= windows[owner[i]]["test"][0], flight=i))
    res = {}
    for key in out:
        err = pd.concat(out[key], ignore_index=True)
        err["window"] = err["flight"] * 100000 + err["window"]
        # a window belongs to the test part when it starts there
        start_test = err.groupby("window")["test"].transform("first").to_numpy()
        res[key] = ModelReplay(err, summarise(err, horizon_s, start_test), growth(err[start_test], horizon_s))
    return Replays(**res)


def rollout_all(states_list, measured_list, vehicle, extension: list[dict], windows: list[dict], horizon: int,
                max_input_gap: int, trim_s: float, explained: Explained, hybrid=None) -> HeldOutRollout:
    """Multi-step rollout (qr.rollout) of the nominal and the extended model (``extension`` added) and the
    references, from the held-out starts of every state table (a flight or a gap-free segment of one):
    the spec's block, with ``explained`` (:func:`qr.diagnose.held_out.summed_r2`).  ``hybrid``: a vehicle
    rolled out beside them (the extended one with its learned torque remainder)."""
    models = {"hold": "hold", "rate_frozen": ("rate_frozen", vehicle), "nominal": (vehicle, list(vehicle.effects)),
              "extended": (vehicle, list(vehicle.effects) + extension)}
    if hybrid is not None:
        models["hybrid"] = (hybrid, list(hybrid.effects))
    owner = flight_of(states_list)
    parts = []
    for i, (st, meas) in enumerate(zip(states_list, measured_list)):
        st, meas, keep = rollout.pieces(st, meas, trim_s)
        keep &= st["t"].to_numpy() >= windows[owner[i]]["test"][0]
        if keep.any():
            parts.append(rollout.score(st, meas, horizon, max_input_gap, models, keep))
    pooled = rollout.pool(parts)
    steps = np.concatenate([np.diff(st["t"].to_numpy(float)) for st in states_list])
    return HeldOutRollout(horizon, {k: rollout.summary(*v) for k, v in pooled.items()}, explained,
                          dt=float(np.median(steps)) if len(steps) else None)
