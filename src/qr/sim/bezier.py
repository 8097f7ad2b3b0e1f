"""The thesis's reference trajectory (eqs. 5.3-5.5): cubic Bezier segments through waypoints.

The correct Bernstein form (eq. 5.5 leaves out the binomial coefficients 3: docs/simulate.md "What we
corrected in the thesis"), each segment taking ``segment_duration_s``; position, velocity, acceleration and
the yaw (``heading`` or ``fixed``) and its rate are analytic at any time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np
import pandas as pd

from ..errors import QrInputError

# eq. 5.3a (columns are waypoints x, y, z) and eq. 5.3b (tangents), as (n, 3) rows
THESIS_WAYPOINTS = np.array([[0, 1, 0, -1, 0, 1],
                             [0, 1, 2, 0, -1, 0],
                             [0, 0.8, 1, 0.5, 1, 0.8]], dtype=float).T
THESIS_TANGENTS = 0.5 * np.array([[0, 0, -1, 0, 1, 0],
                                  [0, 1, 0, -1, 0, 1],
                                  [1, 0, 0, 0, 0, 0]], dtype=float).T
YAW_MODES = {"heading": 0, "fixed": 1}
_MIN_VH2 = 1e-10  # (m/s)^2; below this the heading is taken a hair further along the curve


def control_points(waypoints: np.ndarray, tangents: np.ndarray) -> np.ndarray:
    """``(n-1, 4, 3)`` control points ``[p_k, p_k + v_k, p_{k+1} - v_{k+1}, p_{k+1}]`` (eq. 5.4)."""
    p = np.asarray(waypoints, dtype=float)
    v = np.asarray(tangents, dtype=float)
    return np.stack([p[:-1], p[:-1] + v[:-1], p[1:] - v[1:], p[1:]], axis=1)


@nb.njit(cache=True)
def _curve(t, ctrl, t0, seg_T):
    """p, v, a (world) at time ``t`` (clamped to the trajectory's span)."""
    n = ctrl.shape[0]
    k = 0
    while k < n - 1 and t >= t0[k + 1]:
        k += 1
    T = seg_T[k]
    s = (t - t0[k]) / T
    s = min(max(s, 0.0), 1.0)
    P0, P1, P2, P3 = ctrl[k, 0], ctrl[k, 1], ctrl[k, 2], ctrl[k, 3]
    r = 1.0 - s
    p = r**3 * P0 + 3 * r * r * s * P1 + 3 * r * s * s * P2 + s**3 * P3
    d1 = 3 * r * r * (P1 - P0) + 6 * r * s * (P2 - P1) + 3 * s * s * (P3 - P2)
    d2 = 6 * r * (P2 - 2 * P1 + P0) + 6 * s * (P3 - 2 * P2 + P1)
    if t > t0[n - 1] + seg_T[n - 1] or t < 0.0:  # outside: hold the end point, no motion
        return p, np.zeros(3), np.zeros(3)
    return p, d1 / T, d2 / (T * T)


@nb.njit(cache=True)
def _heading(t, ctrl, t0, seg_T):
    _, v, a = _curve(t, ctrl, t0, seg_T)
    vh2 = v[0] * v[0] + v[1] * v[1]
    if vh2 < _MIN_VH2:  # at rest horizontally (e.g. the vertical start): the limit along the curve
        _, v, a = _curve(t + 1e-4 * seg_T[0], ctrl, t0, seg_T)
        vh2 = v[0] * v[0] + v[1] * v[1]
        if vh2 < _MIN_VH2:
            return math.nan, 0.0
    return math.atan2(v[1], v[0]), (v[0] * a[1] - v[1] * a[0]) / vh2


@nb.njit(cache=True)
def bezier_reference(t, ctrl, t0, seg_T, yaw_mode, yaw0, yaw_grid, grid_dt):
    """``p, v, a, yaw, yaw_rate`` at time ``t`` (numba; the controller's reference)."""
    p, v, a = _curve(t, ctrl, t0, seg_T)
    if yaw_mode == 1:
        return p, v, a, yaw0, 0.0
    raw, rate = _heading(t, ctrl, t0, seg_T)
    # the grid holds the unwrapped heading: pick the branch of atan2 nearest to it
    i = min(max(int(t / grid_dt), 0), yaw_grid.shape[0] - 2)
    f = min(max(t / grid_dt - i, 0.0), 1.0)
    ref = (1 - f) * yaw_grid[i] + f * yaw_grid[i + 1]
    if math.isnan(raw):
        return p, v, a, ref, 0.0
    yaw = raw + 2 * math.pi * round((ref - raw) / (2 * math.pi))
    return p, v, a, yaw, rate


@dataclass
class BezierTrajectory:
    ctrl: np.ndarray  # (S, 4, 3) control points
    segment_durations: np.ndarray  # (S,) s
    yaw_mode: str = "heading"
    yaw0: float = 0.0  # rad, the yaw of yaw: fixed (and before any horizontal motion)

    def __post_init__(self):
        self.t0 = np.concatenate([[0.0], np.cumsum(self.segment_durations)[:-1]])
        self._grid_dt = float(self.segment_durations.min()) / 2000.0
        t = np.arange(0.0, self.duration + 2 * self._grid_dt, self._grid_dt)
        raw = np.array([_heading(float(ti), self.ctrl, self.t0, self.segment_durations)[0] for ti in t])
        ok = np.isfinite(raw)
        if not ok.any():
            raw[:] = self.yaw0
        else:
            raw = np.interp(t, t[ok], raw[ok])  # fill rests with the nearest heading
        self._yaw_grid = np.unwrap(raw)

    @property
    def duration(self) -> float:
        return float(self.segment_durations.sum())

    @property
    def waypoints(self) -> np.ndarray:
        return np.vstack([self.ctrl[:, 0], self.ctrl[-1:, 3]])

    def args(self):
        return (self.ctrl, self.t0, self.segment_durations, YAW_MODES[self.yaw_mode], float(self.yaw0),
                self._yaw_grid, self._grid_dt)

    def at(self, t: float):
        """``p, v, a`` (3,), yaw, yaw rate at time ``t``."""
        return bezier_reference(float(t), *self.args())

    def sample(self, points_per_segment: int = 1000) -> pd.DataFrame:
        """The trajectory table: ``points_per_segment`` samples per segment (thesis: 1000)."""
        t = np.concatenate([t0 + T * np.arange(points_per_segment) / points_per_segment
                            for t0, T in zip(self.t0, self.segment_durations)] + [[self.duration]])
        rows = [self.at(ti) for ti in t]
        df = pd.DataFrame({"t": t})
        for j, ax in enumerate("xyz"):
            df[f"p{ax}"] = [r[0][j] for r in rows]
        for j, ax in enumerate("xyz"):
            df[f"v{ax}"] = [r[1][j] for r in rows]
        for j, ax in enumerate("xyz"):
            df[f"a{ax}"] = [r[2][j] for r in rows]
        df["yaw"] = [r[3] for r in rows]
        df["yaw_rate"] = [r[4] for r in rows]
        return df


def bezier_trajectory(waypoints=THESIS_WAYPOINTS, tangents=THESIS_TANGENTS, segment_duration_s=5.0,
                      yaw: str = "heading", yaw0: float = 0.0, origin=(0.0, 0.0, 0.0)) -> BezierTrajectory:
    """Bezier trajectory through ``waypoints`` (n, 3) with ``tangents`` (n, 3) (eqs. 5.3-5.4)."""
    p = np.asarray(waypoints, dtype=float)
    v = np.asarray(tangents, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 2 or v.shape != p.shape:
        raise QrInputError("sim.trajectory", f"waypoints {p.shape} and tangents {v.shape} do not match",
                           "give n >= 2 waypoints and n tangents as rows [x, y, z]")
    if yaw not in YAW_MODES:
        raise QrInputError("simulate.trajectory.yaw", f"unknown yaw mode {yaw!r}", f"use one of {list(YAW_MODES)}")
    T = np.broadcast_to(np.asarray(segment_duration_s, dtype=float), (len(p) - 1,)).copy()
    if not np.all(T > 0):
        raise QrInputError("simulate.trajectory.segment_duration_s", f"segment durations {T} must be positive",
                           "give a positive time per segment (the time scaling)")
    ctrl = control_points(p + np.asarray(origin, dtype=float), v)
    return BezierTrajectory(np.ascontiguousarray(ctrl), T, yaw, float(yaw0))


def from_config(cfg: dict) -> BezierTrajectory:
    """Trajectory from a ``sim.trajectory`` mapping (waypoints/tangents as rows x, y, z like eq. 5.3)."""
    cfg = dict(cfg or {})
    wp = np.asarray(cfg.get("waypoints", THESIS_WAYPOINTS.T), dtype=float).T
    tg = float(cfg.get("tangent_scale", 1.0)) * np.asarray(cfg.get("tangents", THESIS_TANGENTS.T), dtype=float).T
    return bezier_trajectory(wp, tg, cfg.get("segment_duration_s", 5.0), cfg.get("yaw", "heading"),
                             float(cfg.get("yaw0", 0.0)), cfg.get("origin", (0.0, 0.0, 0.0)))
