"""The simulation against the logged flight, at the log's pose stamps: position, attitude, rotor speeds and
thrust (RMSE, max, where they part), per flight and pooled over flights."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np


class Track(NamedTuple):
    """A flight at the pose stamps (logged or simulated; NaN where it has nothing): position (n, 3), attitude
    quaternion (n, 4), rotor speeds (n, 4), collective thrust (n,)."""

    p: np.ndarray
    q: np.ndarray
    u: np.ndarray
    thrust: np.ndarray


@dataclass(frozen=True)
class Errors:
    """One model on one flight (or pooled): sums for pooling beside the summaries.  ``parts_*``: seconds from
    the replay's start to the first sample whose error exceeds the threshold (None: never)."""

    n: int
    position_sse: float
    position_max: float
    position_parts_at: float | None
    attitude_sse: float  # deg²
    attitude_max: float
    attitude_parts_at: float | None
    rotor_sse: float
    rotor_n: int
    rotor_max: float
    rotor_mean_logged: float
    thrust_sse: float
    thrust_n: int
    thrust_max: float
    diverged_at_s: float | None = None

    def summary(self, unit: str, thrust_kind: str) -> dict:
        rmse = _rmse(self.rotor_sse, self.rotor_n)
        return {
            "position": {"rmse_m": _rmse(self.position_sse, self.n), "max_m": _num(self.position_max),
                         "parts_at_s": self.position_parts_at},
            "attitude": {"rmse_deg": _rmse(self.attitude_sse, self.n), "max_deg": _num(self.attitude_max),
                         "parts_at_s": self.attitude_parts_at},
            "rotor_speed": {"rmse": rmse, "max": _num(self.rotor_max),
                            "rmse_percent": (100.0 * rmse / self.rotor_mean_logged
                                             if rmse is not None and self.rotor_mean_logged > 0 else None),
                            "unit": unit},
            "thrust": {"rmse_N": _rmse(self.thrust_sse, self.thrust_n), "max_N": _num(self.thrust_max),
                       "kind": thrust_kind},
            "diverged_at_s": self.diverged_at_s,
            "samples": self.n,
        }


def _rmse(sse, n):
    return math.sqrt(sse / n) if n else None


def _num(x):
    return float(x) if np.isfinite(x) else None


def _first_above(t, e, threshold, t0):
    above = np.flatnonzero(e > threshold)
    return float(t[above[0]] - t0) if len(above) else None


def compare(t, t0, logged: Track, simulated: Track, part_position_m: float, part_attitude_deg: float,
            diverged_at_s=None) -> Errors:
    """Errors of ``simulated`` against ``logged`` at stamps ``t``, ``t0`` the replay's start."""
    ep = np.linalg.norm(simulated.p - logged.p, axis=1)
    dot = np.abs(np.sum(simulated.q * logged.q, axis=1)) / (
        np.linalg.norm(simulated.q, axis=1) * np.linalg.norm(logged.q, axis=1))
    ea = np.degrees(2.0 * np.arccos(np.clip(dot, 0.0, 1.0)))
    ok = np.isfinite(ep) & np.isfinite(ea)
    eu = simulated.u - logged.u
    uok = np.isfinite(eu)
    et = simulated.thrust - logged.thrust
    tok = np.isfinite(et)
    lu = logged.u[np.isfinite(logged.u) & np.isfinite(simulated.u)]
    return Errors(
        n=int(ok.sum()), position_sse=float(np.sum(ep[ok] ** 2)), position_max=float(np.max(ep[ok], initial=-np.inf)),
        position_parts_at=_first_above(t[ok], ep[ok], part_position_m, t0),
        attitude_sse=float(np.sum(ea[ok] ** 2)), attitude_max=float(np.max(ea[ok], initial=-np.inf)),
        attitude_parts_at=_first_above(t[ok], ea[ok], part_attitude_deg, t0),
        rotor_sse=float(np.sum(eu[uok] ** 2)), rotor_n=int(uok.sum()),
        rotor_max=float(np.max(np.abs(eu[uok]), initial=-np.inf)), rotor_mean_logged=float(lu.mean()) if lu.size else 0.0,
        thrust_sse=float(np.sum(et[tok] ** 2)), thrust_n=int(tok.sum()),
        thrust_max=float(np.max(np.abs(et[tok]), initial=-np.inf)), diverged_at_s=diverged_at_s)


def pool(parts: list[Errors]) -> Errors:
    """Errors over all samples of several flights: sums added, maxima the largest, parting the earliest."""
    def first(xs):
        xs = [x for x in xs if x is not None]
        return min(xs) if xs else None

    def most(xs):
        xs = [x for x in xs if np.isfinite(x)]
        return max(xs) if xs else float("nan")

    n_u = sum(p.rotor_n for p in parts)
    return Errors(
        n=sum(p.n for p in parts), position_sse=sum(p.position_sse for p in parts),
        position_max=most([p.position_max for p in parts]), position_parts_at=first([p.position_parts_at for p in parts]),
        attitude_sse=sum(p.attitude_sse for p in parts), attitude_max=most([p.attitude_max for p in parts]),
        attitude_parts_at=first([p.attitude_parts_at for p in parts]),
        rotor_sse=sum(p.rotor_sse for p in parts), rotor_n=n_u, rotor_max=most([p.rotor_max for p in parts]),
        rotor_mean_logged=(sum(p.rotor_mean_logged * p.rotor_n for p in parts) / n_u) if n_u else 0.0,
        thrust_sse=sum(p.thrust_sse for p in parts), thrust_n=sum(p.thrust_n for p in parts),
        thrust_max=most([p.thrust_max for p in parts]),
        diverged_at_s=first([p.diverged_at_s for p in parts]))
