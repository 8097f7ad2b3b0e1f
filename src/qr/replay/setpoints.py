"""The setpoints a flight tracked: a piecewise-polynomial trajectory flown with a time scale from a start
point, as the Crazyflie's high-level commander flies an uploaded trajectory (crazyswarm's
``uploadTrajectory`` / ``startTrajectory(timescale, relative=True)``).

The file format is crazyswarm's (``figure8.csv``): one row per piece, ``duration`` (s) then 8 coefficients
each of x, y, z and yaw, lowest power first, time from the start of the piece; m and rad.  With time
scale ``s`` the commander evaluates the piece at ``t / s``: the flight lasts ``s`` times the sum of the
durations, velocities scale by ``1/s``, accelerations by ``1/s²``.  Relative semantics: the trajectory is
shifted so that its first point is the start point (``origin``); before its start the setpoint is that
point, after its end the last point (the commander holds it).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import QrInputError

AXES = ("x", "y", "z", "yaw")
ORDER = 8  # coefficients per axis and piece (7th-order polynomials)


@dataclass(frozen=True)
class PiecewisePolynomial:
    """The pieces of a trajectory: ``durations`` (n,), ``coeffs`` (n, 4, 8): x, y, z, yaw; lowest power
    first."""

    durations: np.ndarray
    coeffs: np.ndarray
    name: str = "trajectory"

    @property
    def duration(self) -> float:
        return float(self.durations.sum())

    @property
    def starts(self) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(self.durations)])

    def evaluate(self, tau: np.ndarray, order: int = 4) -> np.ndarray:
        """Derivatives 0..``order`` of x, y, z, yaw at piece time ``tau`` (clamped to the trajectory):
        (order + 1, len(tau), 4), per unit of piece time."""
        tau = np.clip(np.atleast_1d(np.asarray(tau, float)), 0.0, self.duration)
        starts = self.starts
        i = np.clip(np.searchsorted(starts, tau, side="right") - 1, 0, len(self.durations) - 1)
        local = tau - starts[i]
        c = self.coeffs[i]  # (m, 4, 8)
        out = np.zeros((order + 1, len(tau), 4))
        inside = (tau > 0.0) & (tau < self.duration)  # held at the ends: the derivatives are zero there
        for d in range(order + 1):
            for k in range(d, ORDER):
                factor = float(np.prod(np.arange(k - d + 1, k + 1))) if d else 1.0
                out[d] += factor * c[:, :, k] * (local ** (k - d))[:, None]
            if d:
                out[d][~inside] = 0.0
        return out


def read_pieces(path) -> PiecewisePolynomial:
    """A crazyswarm trajectory file (``duration,x^0..x^7,y^0..,z^0..,yaw^0..``), checked."""
    path = Path(path)
    if not path.is_file():
        raise QrInputError(path, "trajectory file does not exist",
                           "give replay.trajectory=PATH of a crazyswarm trajectory CSV (e.g. figure8.csv)")
    import pandas as pd

    try:
        df = pd.read_csv(path)
    except Exception as e:  # noqa: BLE001 - any parse failure is the same user error
        raise QrInputError(path, f"trajectory file cannot be read as CSV ({str(e).splitlines()[0]})",
                           "give a crazyswarm trajectory CSV: duration, x^0..x^7, y^0..y^7, z^0..z^7, yaw^0..yaw^7") from None
    df = df.loc[:, [c for c in df.columns if not str(c).startswith("Unnamed")]]  # a trailing comma
    want = ["duration"] + [f"{a}^{k}" for a in AXES for k in range(ORDER)]
    missing = [c for c in want if c not in df.columns]
    if missing:
        raise QrInputError(path, f"trajectory file lacks the columns {', '.join(missing[:4])}"
                                 + (" …" if len(missing) > 4 else ""),
                           "give a crazyswarm trajectory CSV: duration, x^0..x^7, y^0..y^7, z^0..z^7, yaw^0..yaw^7")
    values = df[want].to_numpy(float)
    if len(values) == 0 or not np.isfinite(values).all():
        raise QrInputError(path, "trajectory file has no pieces or a non-numeric cell", "give every piece all 33 numbers")
    dur = values[:, 0]
    if np.any(dur <= 0):
        raise QrInputError(path, f"piece {int(np.flatnonzero(dur <= 0)[0]) + 1} has a duration ≤ 0 s",
                           "give each piece a positive duration (s)")
    return PiecewisePolynomial(dur, values[:, 1:].reshape(len(dur), 4, ORDER), path.name)


@dataclass(frozen=True)
class Setpoints:
    """A trajectory as flown: piece time ``(t - offset_s) / timescale``, shifted to start at ``origin`` (m),
    yaw shifted by ``yaw0`` (rad).  ``at(t)`` gives what the commander hands the controller."""

    trajectory: PiecewisePolynomial
    timescale: float = 1.0
    offset_s: float = 0.0
    origin: tuple = (0.0, 0.0, 0.0)
    yaw0: float = 0.0

    @property
    def end_s(self) -> float:
        return self.offset_s + self.timescale * self.trajectory.duration

    def at(self, t, order: int = 4) -> dict[str, np.ndarray]:
        """Position, velocity, acceleration, jerk, snap (n, 3; world, SI) and yaw, its rate and acceleration
        (n,) at log times ``t`` (derivatives above ``order`` are zero)."""
        s = self.timescale
        d = np.zeros((5, len(np.atleast_1d(t)), 4))
        d[:order + 1] = self.trajectory.evaluate((np.atleast_1d(np.asarray(t, float)) - self.offset_s) / s, order)
        start = self.trajectory.evaluate(np.array([0.0]), order=0)[0, 0]
        shift = np.asarray(self.origin, float) - start[:3]
        scale = [1.0, 1 / s, 1 / s**2, 1 / s**3, 1 / s**4]
        return {"p": d[0, :, :3] + shift, "v": d[1, :, :3] * scale[1], "a": d[2, :, :3] * scale[2],
                "j": d[3, :, :3] * scale[3], "s": d[4, :, :3] * scale[4],
                "yaw": d[0, :, 3] - start[3] + self.yaw0, "yaw_rate": d[1, :, 3] * scale[1],
                "yaw_acc": d[2, :, 3] * scale[2]}

    def position(self, t) -> np.ndarray:
        return self.at(t)["p"]
