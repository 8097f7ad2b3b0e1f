"""An independent check of the force label: the on-board accelerometer, where the log has one.

The motion-capture label is ``f_a = m (a_b − Rᵀg) − [0, 0, T]``: twice-differentiated positions and
the attitude's view of gravity.  An accelerometer measures the specific force ``a_b − Rᵀg`` itself,
so ``m·acc − [0, 0, T]`` is the same label from a different sensor, with the same rotor-map thrust:
their difference is ``m`` times the difference of the two specific forces, free of any model.  What
the two share is the vehicle's physics; a constant difference is a tilt of the motion-capture frame
against gravity (``m g sin θ`` in x or y) or an accelerometer bias; a difference that follows the
motion is a lag or a scale error of one sensor (the accelerometer sits off the CG too: ω × (ω × r)).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd

from ..dynamics import residuals
from ..flight import ACCEL, on_stamps
from ..states import ROTORS, signals


@dataclass(frozen=True)
class AccelerometerCheck:
    """The two force labels, per body axis x, y, z (N): their means and difference, their correlation sample by
    sample and in ``slow_s`` means (None: a constant label), the RMS of the difference less its mean; the
    tilt of the motion-capture frame the x/y difference would be."""

    tilt_deg: float
    samples: int
    mean_mocap: list[float]
    mean_accelerometer: list[float]
    difference: list[float]
    correlation: list[float | None]
    correlation_slow: list[float | None]
    slow_s: float
    rms_difference: list[float]

    def record(self) -> dict:
        """``diagnosis.json``'s ``accelerometer_check``."""
        return asdict(self)


def labels(st: pd.DataFrame, meas: pd.DataFrame, vehicle) -> tuple[np.ndarray, np.ndarray]:
    """(motion-capture force label, accelerometer force label), (N, 3) each, on the state table's rows."""
    meas = on_stamps(meas, st["t"])
    f_m = residuals(signals(st), vehicle)[:, :3]
    T, _ = vehicle.rotors.thrust_torque(meas[ROTORS].ffill().bfill().to_numpy())
    f_i = vehicle.mass * meas[ACCEL].to_numpy(float)
    f_i[:, 2] -= T
    return f_m, f_i


def _corr(a: np.ndarray, b: np.ndarray) -> list:
    out = []
    for k in range(a.shape[1]):
        sa, sb = a[:, k].std(), b[:, k].std()
        out.append(float(np.mean((a[:, k] - a[:, k].mean()) * (b[:, k] - b[:, k].mean())) / (sa * sb))
                   if sa > 0 and sb > 0 else None)
    return out


def accelerometer_check(states_list, measured_list, vehicle, trim_s: float,
                        slow_s: float = 0.25) -> AccelerometerCheck | None:
    """Per axis: the two labels' means and their difference (N), their correlation sample by sample and
    in ``slow_s`` means, and the RMS of their difference less its mean; the tilt of the motion-capture
    frame the x/y difference would be (``tilt_deg``); None without an accelerometer."""
    fm, fi, sm, si = [], [], [], []
    for st, meas in zip(states_list, measured_list):
        if not all(c in meas.columns for c in ACCEL):
            continue
        a, b = labels(st, meas, vehicle)
        t = st["t"].to_numpy()
        ok = (t >= t[0] + trim_s) & (t <= t[-1] - trim_s) & np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
        if ok.sum() < 10:
            continue
        fm.append(a[ok])
        fi.append(b[ok])
        k = max(1, int(round(slow_s / np.median(np.diff(t)))))
        n = ok.sum() // k
        if n >= 2:
            sm.append(a[ok][:n * k].reshape(n, k, 3).mean(axis=1))
            si.append(b[ok][:n * k].reshape(n, k, 3).mean(axis=1))
    if not fm:
        return None
    fm, fi = np.vstack(fm), np.vstack(fi)
    d = fm - fi
    slow = _corr(np.vstack(sm), np.vstack(si)) if sm else [None] * 3
    dx, dy = d[:, 0].mean(), d[:, 1].mean()
    tilt = float(np.degrees(np.arcsin(min(1.0, np.hypot(dx, dy) / (vehicle.mass * 9.81)))))
    return AccelerometerCheck(tilt, int(len(fm)), fm.mean(axis=0).tolist(), fi.mean(axis=0).tolist(),
                              d.mean(axis=0).tolist(), _corr(fm, fi), slow, slow_s,
                              np.sqrt(((d - d.mean(axis=0)) ** 2).mean(axis=0)).tolist())


def statement(check: AccelerometerCheck) -> str:
    """One sentence for the report: the constant difference read as a tilt of the mocap frame."""
    return (f"The accelerometer's force label (m·acc − T) and the motion-capture one differ by a constant "
            f"({', '.join(f'{1e3 * x:+.1f}' for x in check.difference)}) mN in body x, y, z: in x and y, "
            f"a motion-capture frame tilted {check.tilt_deg:.2f}° against gravity, or an accelerometer bias; what "
            f"both labels share (correlation in {check.slow_s:g} s means: "
            f"{', '.join('–' if c is None else f'{c:.2f}' for c in check.correlation_slow)}) is the vehicle's.")
