"""The Crazyflie firmware's Lee controller (``controller_lee.c``: Lee, Leok & McClamroch, CDC 2010) as the
IMRCLab flights flew it, written from its equations: the position and attitude loops, which firmware version
and why, and how well it reproduces the logged thrust and torques: docs/replay.md "The controller as the
firmware computes it" (tests/replay/test_lee_firmware.py).
"""

from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numba as nb
import numpy as np

from ..errors import QrInputError
from .controller import Command, Controller

GRAVITY = 9.81  # m/s², the firmware's GRAVITY_MAGNITUDE

# gain vector layout of the compiled kernel
G_MASS, G_J, G_KP, G_KPL, G_KD, G_KDL, G_KI, G_KR, G_KW, G_KIR, G_DT = 0, 1, 4, 7, 8, 11, 12, 15, 18, 21, 24
N_G = 25


@functools.lru_cache(maxsize=1)
def _firmware_defaults() -> dict:
    """The firmware's defaults: ``conf/controller/lee.yaml`` (their one place)."""
    import yaml

    from ..shipped import CONF_DIR

    d = yaml.safe_load((Path(CONF_DIR) / "controller" / "lee.yaml").read_text())
    return {k: v for k, v in d.items() if k != "name"}


@dataclass(frozen=True)
class LeeGains:
    """The controller's parameters, with the firmware's names (``conf/controller/lee.yaml`` says what each is
    and holds the defaults: :meth:`from_dict` fills what is not given from there)."""

    mass: float | None  # kg, ctrlLee.mass; None: found from the flight, else the vehicle's
    J: tuple  # kg m², ctrlLee.J_x/y/z
    Kpos_P: tuple  # 1/s²
    Kpos_P_limit: float  # m
    Kpos_D: tuple  # 1/s
    Kpos_D_limit: float  # m/s
    Kpos_I: tuple  # 1/s³
    KR: tuple  # N m / rad
    Komega: tuple  # N m s / rad
    KI: tuple  # N m / (rad s)
    rate_hz: float  # ATTITUDE_RATE

    VECTORS = ("J", "Kpos_P", "Kpos_D", "Kpos_I", "KR", "Komega", "KI")

    @classmethod
    def firmware(cls) -> LeeGains:
        return cls.from_dict({})

    @classmethod
    def from_dict(cls, d: dict) -> LeeGains:
        """The gains of ``d`` (the config group's keys; those not given: the firmware's defaults), checked."""
        d = {k: v for k, v in dict(d).items() if k != "name"}
        known = set(cls.__dataclass_fields__)
        bad = sorted(set(d) - known)
        if bad:
            raise QrInputError(f"controller.{bad[0]}", "is not a parameter of the Lee controller",
                               f"use one of {', '.join(sorted(known))} (conf/controller/lee.yaml)")
        defaults = _firmware_defaults()
        out = {}
        for k in known:
            v = d.get(k, defaults.get(k))
            if k in cls.VECTORS:
                try:
                    vals = tuple(float(x) for x in v)
                except (TypeError, ValueError):
                    vals = ()
                if len(vals) != 3 or not all(math.isfinite(x) and x >= 0 for x in vals) \
                        or (k == "J" and min(vals) <= 0):
                    raise QrInputError(f"controller.{k}", f"{v!r} is not three {'positive' if k == 'J' else 'non-negative'}"
                                       " numbers", f"e.g. controller.{k}=[{','.join(str(x) for x in defaults[k])}]")
                out[k] = vals
            elif k == "mass" and v is None:
                out[k] = None
            else:
                try:
                    x = float(v)
                except (TypeError, ValueError):
                    x = float("nan")
                if not (math.isfinite(x) and x > 0):
                    raise QrInputError(f"controller.{k}", f"{v!r} is not a positive number",
                                       f"e.g. controller.{k}={defaults.get(k) if k != 'mass' else 0.037}")
                out[k] = x
        return cls(**out)

    def scaled_to(self, inertia, mass: float) -> LeeGains:
        """The gains for another vehicle: the attitude gains scaled by its inertia over this one's (the same
        attitude loop in rad/s²), its inertia and mass.  For flights a simulator makes under this controller
        on a vehicle other than the Crazyflie (``qr synth --controller lee``)."""
        r = np.asarray(inertia, float) / np.asarray(self.J, float)
        return replace(self, J=tuple(float(x) for x in inertia), mass=float(mass),
                       KR=tuple(float(x) for x in np.asarray(self.KR) * r),
                       Komega=tuple(float(x) for x in np.asarray(self.Komega) * r),
                       KI=tuple(float(x) for x in np.asarray(self.KI) * r))

    def vector(self, mass: float) -> np.ndarray:
        G = np.zeros(N_G)
        G[G_MASS] = mass
        G[G_J:G_J + 3] = self.J
        G[G_KP:G_KP + 3] = self.Kpos_P
        G[G_KPL] = self.Kpos_P_limit
        G[G_KD:G_KD + 3] = self.Kpos_D
        G[G_KDL] = self.Kpos_D_limit
        G[G_KI:G_KI + 3] = self.Kpos_I
        G[G_KR:G_KR + 3] = self.KR
        G[G_KW:G_KW + 3] = self.Komega
        G[G_KIR:G_KIR + 3] = self.KI
        G[G_DT] = 1.0 / self.rate_hz
        return G

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


@nb.njit(cache=True)
def position_loop(p, v, R, sp_p, sp_v, sp_a, yaw, G, integ):
    """Collective thrust (N) and desired attitude ``R_d`` (3 x 3); ``integ[0:3]`` (the position integral)
    advanced; both integrals reset (``integ[:] = 0``) when the thrust is below 0.01 N, as the firmware."""
    F = np.empty(3)
    dt = G[G_DT]
    for i in range(3):
        ep = min(max(sp_p[i] - p[i], -G[G_KPL]), G[G_KPL])
        ev = min(max(sp_v[i] - v[i], -G[G_KDL]), G[G_KDL])
        integ[i] += dt * ep
        F[i] = sp_a[i] + G[G_KD + i] * ev + G[G_KP + i] * ep + G[G_KI + i] * integ[i]
    F[2] += GRAVITY
    T = G[G_MASS] * (F[0] * R[0, 2] + F[1] * R[1, 2] + F[2] * R[2, 2])
    if T < 0.01:
        integ[:] = 0.0
    Rd = np.eye(3)
    if T > 0.0:
        n = math.sqrt(F[0] * F[0] + F[1] * F[1] + F[2] * F[2])
        Rd[0, 2], Rd[1, 2], Rd[2, 2] = F[0] / n, F[1] / n, F[2] / n
    cy, sy = math.cos(yaw), math.sin(yaw)
    z0, z1, z2 = Rd[0, 2], Rd[1, 2], Rd[2, 2]
    y0, y1, y2 = -z2 * sy, z2 * cy, z0 * sy - z1 * cy  # z_d x x_c
    n = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    if n > 0.0:
        Rd[0, 1], Rd[1, 1], Rd[2, 1] = y0 / n, y1 / n, y2 / n
    Rd[0, 0] = Rd[1, 1] * z2 - Rd[2, 1] * z1
    Rd[1, 0] = Rd[2, 1] * z0 - Rd[0, 1] * z2
    Rd[2, 0] = Rd[0, 1] * z1 - Rd[1, 1] * z0
    return T, Rd


@nb.njit(cache=True)
def desired_rates(T, Rd, sp_j, yaw_rate, mass):
    """``ω_d`` (rad/s, in the desired body frame) from the jerk (zero roll/pitch rate where T = 0)."""
    wd = np.zeros(3)
    if T != 0.0:
        zj = Rd[0, 2] * sp_j[0] + Rd[1, 2] * sp_j[1] + Rd[2, 2] * sp_j[2]
        h = np.empty(3)
        for i in range(3):
            h[i] = mass / T * (sp_j[i] - zj * Rd[i, 2])
        wd[0] = -(h[0] * Rd[0, 1] + h[1] * Rd[1, 1] + h[2] * Rd[2, 1])
        wd[1] = h[0] * Rd[0, 0] + h[1] * Rd[1, 0] + h[2] * Rd[2, 0]
    wd[2] = yaw_rate * Rd[2, 2]
    return wd


@nb.njit(cache=True, inline="always")
def _atb(A, B, i, j):
    """``(Aᵀ B)[i, j]`` in index order (no BLAS: the same last bits on every machine)."""
    return A[0, i] * B[0, j] + A[1, i] * B[1, j] + A[2, i] * B[2, j]


@nb.njit(cache=True)
def attitude_loop(R, w, Rd, wd, G, integ):
    """Body torque (N m) and ``ω_r`` (rad/s); ``integ[3:6]`` (the attitude integral) advanced."""
    eR = 0.5 * np.array([_atb(Rd, R, 2, 1) - _atb(R, Rd, 2, 1), _atb(Rd, R, 0, 2) - _atb(R, Rd, 0, 2),
                         _atb(Rd, R, 1, 0) - _atb(R, Rd, 1, 0)])
    wr = np.zeros(3)
    for i in range(3):
        for j in range(3):
            wr[i] += _atb(R, Rd, i, j) * wd[j]
    J = G[G_J:G_J + 3]
    Jw = J * w
    gyro = np.array([w[1] * Jw[2] - w[2] * Jw[1], w[2] * Jw[0] - w[0] * Jw[2], w[0] * Jw[1] - w[1] * Jw[0]])
    tau = np.empty(3)
    for i in range(3):
        integ[3 + i] += G[G_DT] * eR[i]
        tau[i] = -G[G_KR + i] * eR[i] - G[G_KW + i] * (w[i] - wr[i]) - G[G_KIR + i] * integ[3 + i] + gyro[i]
    return tau, wr


@nb.njit(cache=True)
def lee_step(p, v, R, w, sp_p, sp_v, sp_a, sp_j, yaw, yaw_rate, G, integ):
    """One controller update: (thrust N, torque (3,) N m, R_d, ω_r)."""
    T, Rd = position_loop(p, v, R, sp_p, sp_v, sp_a, yaw, G, integ)
    wd = desired_rates(T, Rd, sp_j, yaw_rate, G[G_MASS])
    tau, wr = attitude_loop(R, w, Rd, wd, G, integ)
    return T, tau, Rd, wr


@dataclass
class LeeController(Controller):
    """The firmware's Lee controller behind :class:`qr.replay.controller.Controller`."""

    gains: LeeGains = field(default_factory=LeeGains.firmware)
    name = "lee"

    def __post_init__(self):
        self.rate_hz = self.gains.rate_hz
        self._G = None
        self._integ = np.zeros(6)

    def reset(self, vehicle, mass: float) -> None:
        m = self.gains.mass if self.gains.mass is not None else mass
        self._G = self.gains.vector(float(m))
        self._integ = np.zeros(6)

    @property
    def mass(self) -> float:
        return float(self._G[G_MASS])

    def __call__(self, t, state, setpoint) -> Command:
        from ..frames_compiled import quat_to_R

        R = quat_to_R(np.asarray(state.q, float))
        T, tau, _, _ = lee_step(np.asarray(state.p, float), np.asarray(state.v, float), R, np.asarray(state.w, float),
                                setpoint.p, setpoint.v, setpoint.a, setpoint.j, float(setpoint.yaw),
                                float(setpoint.yaw_rate), self._G, self._integ)
        return Command(thrust=float(T), torque=tau)

    def describe(self) -> dict:
        d = {"name": self.name, "rate_hz": float(self.rate_hz), "gains": self.gains.to_dict()}
        if self._G is not None:
            d["gains"]["mass"] = self.mass
        return d
