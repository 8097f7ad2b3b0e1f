"""Closed-loop tracking study (thesis Chapter 5): nominal vs compensated vs oracle controller.

One closed loop (:func:`fly`): the shared TRUE plant with the catalog's effects, flown by the LQR + PD
controller knowing only the NOMINAL vehicle, its acceleration command compensated by ``-R f_est / m``
(nothing, a force model's prediction, or the true ``f_a``: the oracle).  A run stops at the first sign of
divergence (``status = "diverged"``; metrics over the part flown).  docs/simulate.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba as nb
import numpy as np
import pandas as pd

from ..effects import Signals, validate_effect_list
from ..frames import G, euler_zyx, rot_to_quat
from ..states import COLUMNS
from ..replay.fly import ideal_speeds
from ..replay.lee import lee_step
from .control import C_UMAX, C_UMIN, Gains, control, controller_params
from ..frames_compiled import quat_to_R
from ..plant_state import N_X, P_DELAY, P_MASS, P_TAU, X_POS, X_QUAT, X_RATE, X_ROTORS, X_VEL
from .plant import delayed_speeds, history_buffer, plant_accels, rk4_step, true_params

ORACLE = "oracle"
REF_COLUMNS = ["ref_px", "ref_py", "ref_pz", "ref_vx", "ref_vy", "ref_vz", "ref_yaw"]
RD_COLUMNS = ["qdw", "qdx", "qdy", "qdz"]  # desired attitude (from the position loop)
F_TRUE = ["f_true_x", "f_true_y", "f_true_z"]  # true f_a (body, N) at the logged state
F_EST = ["f_est_x", "f_est_y", "f_est_z"]  # what the controller compensated (body, N)
LOG_COLUMNS = COLUMNS + REF_COLUMNS + RD_COLUMNS + F_TRUE + F_EST


@dataclass
class Limits:
    """Divergence: any of these ends the run (``status = diverged``)."""

    max_position_error_m: float = 5.0
    max_speed_m_s: float = 30.0
    max_accel_g: float = 20.0


@dataclass
class SimSettings:
    rate: float = 1000.0  # Hz, control and integration (>= 500)
    log_rate: float = 100.0  # Hz
    duration: float | None = None  # s; None: the trajectory's
    gains: Gains = field(default_factory=Gains)
    limits: Limits = field(default_factory=Limits)
    controller: str = "lqr"  # lqr: the thesis's LQR + PD; lee: the Crazyflie firmware's (qr.replay.lee), the gains of
    #                          conf/controller/lee.yaml, attitude gains scaled to the vehicle's inertia


@dataclass
class Plant:
    """The TRUE vehicle: nominal vehicle + catalog effects (physics) + an injected force model.

    ``a_b_mode`` says how a force model that takes ``a_b`` as input is evaluated:
    ``lagged`` with the acceleration of the previous step (the thesis's simulation,
    eq. 5.13), ``implicit`` by solving ``m a_b = ... + W_a a_b + ...`` for a
    consistent acceleration (linear models only; the physically meaningful reading).
    """

    vehicle: object
    effects: list[dict] = field(default_factory=list)
    force: object | None = None
    a_b_mode: str = "lagged"

    def __post_init__(self):
        self.effects = validate_effect_list(self.effects)
        if self.a_b_mode not in ("lagged", "implicit"):
            raise ValueError(f"a_b_mode {self.a_b_mode!r}: use lagged or implicit")
        if self.a_b_mode == "implicit" and self.force is not None and not hasattr(self.force, "block"):
            raise ValueError("a_b_mode implicit needs a linear force model")


@dataclass
class FlightResult:
    log: pd.DataFrame
    status: str  # ok | diverged
    message: str
    t_end: float

    @property
    def diverged(self) -> bool:
        return self.status != "ok"

    def metrics(self) -> dict:
        return tracking_metrics(self.log) | {"status": self.status, "t_end_s": self.t_end}


class Reference:
    """Adapter: anything with ``at(t) -> p, v, a, yaw, yaw_rate`` and a ``duration``."""

    def __init__(self, fn, duration):
        self._fn = fn
        self.duration = float(duration)

    def at(self, t):
        return self._fn(t)


def random_reference(rng: np.random.Generator, duration: float, cfg=None) -> Reference:
    """``qr synth``'s random trajectory (identification flights)."""
    from .trajectory import random_trajectory, reference

    traj = random_trajectory(rng, duration, cfg)
    args = traj.args()
    return Reference(lambda t: reference(float(t), *args), duration)


@nb.njit(cache=True)
def true_force(x, u_eff, u_meas, P, f_ext, mass, ct_row):
    """The ``f_a`` the plant produces now: ``m R^T (a - g) - T_nom(u_meas) e3`` (eq. 4.34, true states)."""
    a, _ = plant_accels(x, u_eff, P, f_ext, np.zeros(3))
    R = quat_to_R(x[X_QUAT])
    a[2] += G
    f = mass * (R.T @ a)
    T = 0.0
    for i in range(4):
        T += ct_row[i] * u_meas[i] * u_meas[i]
    f[2] -= T
    return f


def _signals1(x, R, acc, alpha, u, u_dot) -> Signals:
    return Signals(R[None], (R.T @ x[X_VEL])[None], (R.T @ acc)[None], x[X_RATE][None], alpha[None], u[None],
                   u_dot[None], x[X_POS][None])


def initial_state(vehicle, ref) -> np.ndarray:
    """Hover on the reference at t = 0 (position, velocity, yaw), rotors at the nominal hover speed."""
    p, v, _, yaw, _ = ref.at(0.0)
    x = np.zeros(N_X)
    x[X_POS] = p
    x[X_VEL] = v
    x[X_QUAT] = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
    x[X_ROTORS] = vehicle.hover_speed
    return x


@nb.njit(cache=True)
def _measure(x, hist, u0, k, d_steps, P, f_inj, u_cmd, tau_m):
    """Rotor speeds acting now, acceleration and angular acceleration with the held force, R, u̇."""
    u_meas = x[X_ROTORS].copy()
    u_eff = delayed_speeds(hist, u0, k, 0.0, d_steps) if d_steps > 0 else u_meas
    acc, alpha = plant_accels(x, u_eff, P, f_inj, np.zeros(3))
    return u_meas, u_eff, acc, alpha, quat_to_R(x[X_QUAT]), (u_cmd - u_meas) / tau_m


# divergence codes
OK, NOT_FINITE, POSITION, SPEED, ACCEL = 0, 1, 2, 3, 4


@nb.njit(cache=True)
def _lee(x, p_ref, v_ref, a_ref, yaw, yaw_rate, a_comp, C, L, integ, Binv):
    """The Lee controller's rotor-speed command (the vehicle's inverse rotor map, clipped to its limits) and its
    desired attitude; the disturbance estimate enters the acceleration feed-forward as the firmware's does."""
    T, tau, Rd, _ = lee_step(x[X_POS].copy(), x[X_VEL].copy(), quat_to_R(x[X_QUAT]), x[X_RATE].copy(), p_ref, v_ref,
                             a_ref + a_comp, np.zeros(3), yaw, yaw_rate, L, integ)
    u = ideal_speeds(Binv, T, tau)
    for i in range(4):
        u[i] = min(max(u[i], C[C_UMIN]), C[C_UMAX])
    return u, Rd


@nb.njit(cache=True)
def _act(x, t, k, n_steps, p_ref, v_ref, a_ref, yaw, yaw_rate, f_est, f_inj, acc, alpha, u_meas, u_dot, u_eff,
         m_nom, ct_row, C, P, dt, hist, u0, limits, out, j, do_log, L, integ, Binv):
    """Divergence check, control with compensation, logging, one RK4 step."""
    zero = np.zeros(3)
    for i in range(N_X):
        if not math.isfinite(x[i]):
            return x, u_meas, NOT_FINITE, 0.0
    for i in range(3):
        if not (math.isfinite(acc[i]) and math.isfinite(f_inj[i]) and math.isfinite(f_est[i])):
            return x, u_meas, NOT_FINITE, 0.0
    p, v = X_POS.start, X_VEL.start
    e = math.sqrt((x[p] - p_ref[0]) ** 2 + (x[p + 1] - p_ref[1]) ** 2 + (x[p + 2] - p_ref[2]) ** 2)
    if e > limits[0]:
        return x, u_meas, POSITION, e
    sp = math.sqrt(x[v] ** 2 + x[v + 1] ** 2 + x[v + 2] ** 2)
    if sp > limits[1]:
        return x, u_meas, SPEED, sp
    am = math.sqrt(acc[0] ** 2 + acc[1] ** 2 + acc[2] ** 2)
    if am > limits[2] * G:
        return x, u_meas, ACCEL, am / G
    R = quat_to_R(x[X_QUAT])
    a_comp = -(R @ f_est) / m_nom
    if L.shape[0] > 0:
        u_cmd, Rd = _lee(x, p_ref, v_ref, a_ref, yaw, yaw_rate, a_comp, C, L, integ, Binv)
    else:
        u_cmd, Rd = control(x, p_ref, v_ref, a_ref, yaw, yaw_rate, a_comp, C)
    if do_log:
        f_true = true_force(x, u_eff, u_meas, P, f_inj, m_nom, ct_row)
        row = out[j]
        row[0] = t
        row[1:4] = x[X_POS]
        row[4:7] = x[X_VEL]
        row[7:10] = acc
        row[10:14] = x[X_QUAT]
        row[14:17] = x[X_RATE]
        row[17:20] = alpha
        row[20:24] = u_meas
        row[24:28] = u_dot
        row[28:31] = p_ref
        row[31:34] = v_ref
        row[34] = yaw
        row[35:44] = Rd.ravel()
        row[44:47] = f_true
        row[47:50] = f_est
    if k < n_steps:
        x = rk4_step(x, u_cmd, P, f_inj, zero, dt, hist, u0, k)
    return x, u_cmd, OK, 0.0


@dataclass(frozen=True)
class _Injection:
    """The plant's learned force, injected at every step of :func:`fly` (``a_b_mode``: lagged or implicit)."""

    force: object
    implicit: bool
    m_true: float
    W_a: np.ndarray | None = None  # the model's a_b block (implicit)
    M_eff: np.ndarray | None = None  # m I - W_a
    singular: bool = False  # the model predicts its own label: no solution

    @classmethod
    def of(cls, plant: Plant, m_true: float) -> "_Injection | None":
        force = plant.force
        if force is None:
            return None
        if plant.a_b_mode != "implicit":
            return cls(force, False, m_true)
        W_a = force.block("a_b")
        M_eff = m_true * np.eye(3) - W_a
        return cls(force, True, m_true, W_a, M_eff, bool(np.linalg.cond(M_eff) > 1e12))

    def at(self, x, R, acc, alpha, u_meas, u_dot, u_eff, P):
        """The model's signals, the injected force and the plant's accelerations with it."""
        zero = np.zeros(3)
        # the model sees the acceleration measured before this step's force (thesis eq. 5.13)
        s = _signals1(x, R, acc, alpha, u_meas, u_dot)
        if self.implicit:  # (m I - W_a) a_b = m a0_b + r, with r the prediction at a_b = 0
            a0, _ = plant_accels(x, u_eff, P, zero, zero)
            s0 = _signals1(x, R, zero, alpha, u_meas, u_dot)
            r = self.force.predict(s0)[0]
            a_b = np.full(3, np.inf) if self.singular else np.linalg.solve(self.M_eff, self.m_true * (R.T @ a0) + r)
            f_inj = self.W_a @ a_b + r
        else:
            f_inj = np.asarray(self.force.predict(s)[0], dtype=float)
        acc, alpha = plant_accels(x, u_eff, P, f_inj, zero)
        return s, f_inj, acc, alpha


def fly(ref, plant: Plant, estimator=None, settings: SimSettings | None = None) -> FlightResult:
    """Fly ``ref`` with the plant; ``estimator`` None (nominal), a force model, or :data:`ORACLE`."""
    cfg = settings or SimSettings()
    if cfg.rate < 500:
        raise ValueError(f"simulation rate {cfg.rate} Hz is below 500 Hz")
    veh = plant.vehicle
    dt = 1.0 / cfg.rate
    duration = ref.duration if cfg.duration is None else min(cfg.duration, ref.duration)
    n_steps = int(round(duration / dt))
    log_every = max(1, int(round(cfg.rate / cfg.log_rate)))
    P = true_params(veh, plant.effects)
    C = controller_params(veh, cfg.gains)
    L, integ = np.zeros(0), np.zeros(6)
    if cfg.controller == "lee":
        from ..replay.lee import G_DT, LeeGains

        L = LeeGains.firmware().scaled_to(veh.inertia, veh.mass).vector(float(veh.mass))
        L[G_DT] = dt  # updated every step of the study
    m_nom = float(veh.mass)
    m_true = P[P_MASS]
    ct_row = veh.rotors.matrix[0].copy()
    tau_m = float(P[P_TAU])
    x = initial_state(veh, ref)
    u0 = x[X_ROTORS].copy()
    hist = history_buffer(P, dt, u0)
    d_steps = float(P[P_DELAY] / dt)
    lim = cfg.limits
    limits = np.array([lim.max_position_error_m, lim.max_speed_m_s, lim.max_accel_g])
    f_inj = np.zeros(3)
    f_est = np.zeros(3)
    u_cmd = u0.copy()
    injection = _Injection.of(plant, m_true)
    out = np.zeros((n_steps // log_every + 1, N_RAW))
    j = 0
    status, message, t_end = "ok", "", n_steps * dt
    for k in range(n_steps + 1):
        t = k * dt
        p_ref, v_ref, a_ref, yaw, yaw_rate = ref.at(t)
        u_meas, u_eff, acc, alpha, R, u_dot = _measure(x, hist, u0, k, d_steps, P, f_inj, u_cmd, tau_m)
        s = None
        if injection is not None:
            s, f_inj, acc, alpha = injection.at(x, R, acc, alpha, u_meas, u_dot, u_eff, P)
        if estimator is ORACLE:
            f_est = true_force(x, u_eff, u_meas, P, f_inj, m_nom, ct_row)
        elif estimator is not None:
            s_est = s if s is not None else _signals1(x, R, acc, alpha, u_meas, u_dot)
            f_est = np.asarray(estimator.predict(s_est)[0], dtype=float)
        do_log = k % log_every == 0
        x, u_cmd, code, val = _act(x, t, k, n_steps, p_ref, v_ref, a_ref, yaw, yaw_rate, f_est, f_inj, acc, alpha,
                                   u_meas, u_dot, u_eff, m_nom, ct_row, C, P, dt, hist, u0, limits, out, j, do_log,
                                   L, integ, veh.rotors.inverse.copy())
        if code != OK:
            status, t_end = "diverged", t
            message = f"diverged at t = {t:.3f} s: {_reason(code, val, lim)}; the run was stopped and recorded"
            break
        j += do_log
    return FlightResult(_log_frame(out[:j]), status, message, t_end)


N_RAW = 50  # t, p, v, a, q, ω, α, u, u̇, p_ref, v_ref, yaw_ref, Rd (9), f_true, f_est


def _log_frame(raw: np.ndarray) -> pd.DataFrame:
    Rd = raw[:, 35:44].reshape(-1, 3, 3)
    qd = rot_to_quat(Rd) if len(raw) else np.zeros((0, 4))
    return pd.DataFrame(np.hstack([raw[:, :35], qd, raw[:, 44:50]]), columns=LOG_COLUMNS)


def _reason(code, val, lim: Limits) -> str:
    if code == NOT_FINITE:
        return "the state or the disturbance force is not finite"
    if code == POSITION:
        return f"position error {val:.3g} m > {lim.max_position_error_m} m"
    if code == SPEED:
        return f"speed {val:.3g} m/s > {lim.max_speed_m_s} m/s"
    return f"acceleration {val:.3g} g > {lim.max_accel_g} g"


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def euler_angles(log: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Actual and desired roll, pitch, yaw (rad, (N, 3)); yaw unwrapped (thesis Fig. 5.4)."""
    act = euler_zyx(log[["qw", "qx", "qy", "qz"]].to_numpy())
    des = euler_zyx(log[RD_COLUMNS].to_numpy())
    act[:, 2] = np.unwrap(act[:, 2])
    des[:, 2] = act[:, 2] + _wrap(des[:, 2] - act[:, 2])
    return act, des


def tracking_metrics(log: pd.DataFrame) -> dict:
    """Position RMSE per axis and overall (RMS of the error vector's length), attitude RMSE (deg)."""
    if len(log) == 0:
        return {"rmse_x": 0.0, "rmse_y": 0.0, "rmse_z": 0.0, "rmse": 0.0, "att_rmse_deg": 0.0}
    e = log[["px", "py", "pz"]].to_numpy() - log[["ref_px", "ref_py", "ref_pz"]].to_numpy()
    mse = (e**2).mean(axis=0)
    act, des = euler_angles(log)
    de = _wrap(act - des)
    return {"rmse_x": float(np.sqrt(mse[0])), "rmse_y": float(np.sqrt(mse[1])), "rmse_z": float(np.sqrt(mse[2])),
            "rmse": float(np.sqrt(mse.sum())),
            "att_rmse_deg": float(np.degrees(np.sqrt((de**2).sum(axis=1).mean())))}


def identification_data(plant: Plant, duration: float = 60.0, seed: int = 0, accel_noise: float = 0.0,
                        settings: SimSettings | None = None, trajectory=None) -> tuple[Signals, np.ndarray]:
    """Signals and ``f_a`` labels of a nominal-controller flight along a random trajectory.

    The stand-in for "fly, filter, compute labels" when no learning stage is wired:
    true states, except the body acceleration, which gets white noise of
    ``accel_noise`` m/s² (what a filter leaves); the labels are computed from that
    same noisy ``a_b`` by eq. 4.34, so their noise is ``m`` times it, as on real data.
    """
    from ..dynamics import residual_force
    from ..states import signals

    rng = np.random.default_rng(seed)
    ref = random_reference(rng, duration, trajectory)
    res = fly(ref, plant, None, settings)
    if res.diverged:
        raise RuntimeError(f"identification flight {res.message}")
    s = signals(res.log)
    s.a_b = s.a_b + np.random.default_rng([seed, 1]).normal(0.0, accel_noise, s.a_b.shape)
    return s, residual_force(s.a_b, s.R, s.u, plant.vehicle)
