"""Between the controller and the rotors: the Crazyflie firmware's power distribution, or the vehicle's
inverse rotor map; then the motor map from command to rotor speed (``fit`` from the flight, or ``firmware``).
The firmware's equations and how well they give the logged PWM: docs/replay.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

GRAMS_PER_NEWTON = 1000.0 / 9.81


@dataclass(frozen=True)
class PwmModel:
    """The firmware's force -> PWM model (f in grams per motor, v in V): ``d00 + d10 f + d01 v + d20 f² +
    d11 f v``."""

    d00: float
    d10: float
    d01: float = 0.0
    d20: float = 0.0
    d11: float = 0.0

    def duty(self, force_N, vbat=0.0):
        f = np.asarray(force_N, float) * GRAMS_PER_NEWTON
        return self.d00 + self.d10 * f + self.d01 * vbat + self.d20 * f * f + self.d11 * f * vbat

    def force(self, duty, vbat=0.0):
        """The force (N per motor) the firmware believes a duty gives (the model inverted; 0 below its
        zero-force duty)."""
        duty = np.asarray(duty, float)
        b = self.d10 + self.d11 * np.asarray(vbat, float)
        c = self.d00 + self.d01 * np.asarray(vbat, float) - duty
        if self.d20 == 0.0:
            f = -c / b
        else:
            f = (-b + np.sqrt(np.maximum(b * b - 4 * self.d20 * c, 0.0))) / (2 * self.d20)
        return np.maximum(f, 0.0) / GRAMS_PER_NEWTON

    def vector(self) -> np.ndarray:
        return np.array([self.d00, self.d10, self.d01, self.d20, self.d11])


@dataclass(frozen=True)
class CrazyflieMixer:
    """The firmware's power distribution: arm length (m, CG to motor), thrust-to-torque ratio (m), the PWM
    model."""

    arm_length: float
    thrust_to_torque: float
    pwm: PwmModel

    def duties(self, thrust, torque, vbat: float = 0.0) -> np.ndarray:
        return _duties(float(thrust), np.asarray(torque, float), self.arm_length, self.thrust_to_torque,
                       self.pwm.vector(), float(vbat))

    def thrust_of(self, duties, vbat=0.0) -> np.ndarray:
        """The collective thrust (N) the firmware believes the duties (…, 4) give."""
        return self.pwm.force(duties, np.asarray(vbat, float)[..., None] if np.ndim(vbat) else vbat).sum(axis=-1)

    def to_dict(self) -> dict:
        return {"kind": "crazyflie", "arm_length": self.arm_length, "thrust_to_torque": self.thrust_to_torque,
                "pwm": {k: getattr(self.pwm, k) for k in ("d00", "d10", "d01", "d20", "d11")}}


@nb.njit(cache=True)
def _forces(T, tau, arm_length, t2t):
    a = arm_length / math.sqrt(2.0)
    r = 0.25 / a * tau[0]
    p = 0.25 / a * tau[1]
    y = 0.25 * tau[2] / t2t
    th = 0.25 * T
    return np.array([th - r - p - y, th - r + p + y, th + r + p - y, th + r - p + y])


@nb.njit(cache=True)
def _duties(T, tau, arm_length, t2t, d, vbat):
    f = _forces(T, tau, arm_length, t2t)
    out = np.empty(4)
    for i in range(4):
        g = max(f[i], 0.0) * (1000.0 / 9.81)
        out[i] = d[0] + d[1] * g + d[2] * vbat + d[3] * g * g + d[4] * g * vbat
    top = max(out[0], out[1], out[2], out[3])
    if top > 1.0:
        out -= top - 1.0
    for i in range(4):
        out[i] = max(out[i], 0.0)
    return out


@dataclass(frozen=True)
class MotorMap:
    """Per rotor steady-state rotor speed of a PWM duty: ``u = a + b pwm`` (the vehicle's unit), or the
    firmware's belief through the vehicle's C_T (``firmware``)."""

    kind: str  # "fit" | "firmware"
    a: tuple = (0.0, 0.0, 0.0, 0.0)
    b: tuple = (0.0, 0.0, 0.0, 0.0)
    rms: float | None = None  # of the fit, the vehicle's unit
    tau_s: float | None = None  # the motor time constant the fit assumed

    def speeds(self, duties, mixer: CrazyflieMixer, thrust_coeff: float, vbat: float = 0.0) -> np.ndarray:
        if self.kind == "fit":
            return np.asarray(self.a) + np.asarray(self.b) * np.asarray(duties)
        return np.sqrt(mixer.pwm.force(duties, vbat) / thrust_coeff)

    def to_dict(self) -> dict:
        d = {"kind": self.kind}
        if self.kind == "fit":
            d.update(a=list(self.a), b=list(self.b), rms=self.rms, tau_s=self.tau_s)
        return d


def fit_motor_map(t, duties, speeds, tau_s: float) -> MotorMap:
    """``u = a + b pwm`` per rotor, least squares of the logged rotor speeds on the duties passed through the
    first-order motor response of time constant ``tau_s`` (the same response the simulation applies)."""
    from .alignment import lstsq

    t = np.asarray(t, float)
    duties = np.asarray(duties, float)
    speeds = np.asarray(speeds, float)
    lagged = np.empty_like(duties)
    lagged[0] = duties[0]
    dt = np.diff(t, prepend=t[0])
    for k in range(1, len(t)):  # exact discretisation of ẋ = (pwm - x) / τ with pwm held over each step
        e = math.exp(-dt[k] / tau_s)
        lagged[k] = e * lagged[k - 1] + (1 - e) * duties[k - 1]
    a, b, res = [], [], []
    for i in range(4):
        ok = np.isfinite(lagged[:, i]) & np.isfinite(speeds[:, i])
        A = np.stack([np.ones(ok.sum()), lagged[ok, i]], axis=1)
        c = lstsq(A, speeds[ok, i])
        a.append(float(c[0]))
        b.append(float(c[1]))
        res.append(speeds[ok, i] - A @ c)
    rms = float(np.sqrt(np.mean(np.concatenate(res) ** 2)))
    return MotorMap("fit", tuple(a), tuple(b), rms, float(tau_s))
