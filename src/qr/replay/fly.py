"""One vehicle file flown in closed loop: a controller (:mod:`qr.replay.controller`) at its rate, the mixer,
the rotor limits and the first-order motors, qr's plant (:mod:`qr.sim.plant`: the vehicle's effects, torque
remainder or learned residual) integrated with RK4.  ``qr replay`` and ``qr synth --controller lee`` fly
through this one function, so a synthetic flight replayed with its true vehicle comes back to the last bit.

The controller sees the true state of the tracked point (the motion-capture marker the on-board estimator
fuses: the vehicle's ``marker_offset``, if any): no estimator, no sensor noise, no disturbance beyond the
vehicle file's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from ..frames_compiled import quat_to_R
from ..plant_state import N_X, P_DELAY, P_MARKER, X_POS, X_QUAT, X_RATE, X_ROTORS, X_VEL
from ..sim.plant import cg_from_tracked, history_buffer, plant_accels, rk4_step, tracked_pv, true_params
from .controller import Command, Controller, Setpoint, State
from .lee import LeeController, lee_step
from .mixer import GRAMS_PER_NEWTON, CrazyflieMixer, MotorMap, _duties
from .setpoints import Setpoints

UPSIDE_DOWN = 0.0  # R[2, 2] below this: the vehicle is lost


@dataclass(frozen=True)
class Actuation:
    """What stands between the controller's thrust and torques and the motors: the Crazyflie firmware's
    power distribution and a motor map (``mixer``, ``motor_map``), or neither (the vehicle's inverse rotor
    map); ``vbat`` (V) for a PWM model that uses it."""

    mixer: CrazyflieMixer | None = None
    motor_map: MotorMap | None = None
    vbat: float = 0.0

    def speeds(self, command: Command, vehicle) -> tuple[np.ndarray, np.ndarray | None]:
        """Rotor-speed command (4, before the limits) and the PWM duties (or None)."""
        if command.rotor_speeds is not None:
            return np.asarray(command.rotor_speeds, float), None
        if self.mixer is None:
            return ideal_speeds(vehicle.rotors.inverse, float(command.thrust), np.asarray(command.torque, float)), None
        duties = self.mixer.duties(command.thrust, command.torque, self.vbat)
        return self.motor_map.speeds(duties, self.mixer, vehicle.thrust_coeff, self.vbat), duties


@dataclass(frozen=True)
class Flown:
    """The simulation at its own steps: time (s), the tracked point's position (m), velocity (m/s), the
    attitude (body → world), body rate (rad/s), rotor speeds (the motors', as a sensor reads them; the
    vehicle's unit; with an actuator delay the thrust acts later), the controller's
    collective thrust command (N; NaN for a rotor-speed controller), the PWM duties (or NaN), and the time
    it was stopped as lost (or None).  ``x`` holds the full plant state (CG) for callers that need it."""

    t: np.ndarray
    p: np.ndarray
    v: np.ndarray
    q: np.ndarray
    w: np.ndarray
    u: np.ndarray
    thrust_cmd: np.ndarray
    duties: np.ndarray
    x: np.ndarray
    u_cmd: np.ndarray
    diverged_at_s: float | None = None


def initial_state(vehicle, p, v, q, w, u, P=None) -> np.ndarray:
    """The plant state (CG) of a tracked-point state: position and velocity of the marker (world), attitude
    (body → world, scalar first), body rate, rotor speeds."""
    P = true_params(vehicle, list(vehicle.effects), residual=False) if P is None else P
    x = np.zeros(N_X)
    x[X_POS], x[X_VEL], x[X_QUAT], x[X_RATE], x[X_ROTORS] = p, v, np.asarray(q) / np.linalg.norm(q), w, u
    cg_from_tracked(x, P[P_MARKER].copy())
    return x


class Held:
    """A setpoint held: the position and yaw of ``setpoints`` at ``t0``, at rest."""

    def __init__(self, setpoints, t0: float):
        self.ref = setpoints.at(np.array([t0]), order=0)

    def at(self, t, order: int = 4) -> dict:
        n = len(np.atleast_1d(t))
        out = {k: np.zeros((n, 3)) for k in ("p", "v", "a", "j", "s")}
        out["p"][:] = self.ref["p"][0]
        out.update(yaw=np.full(n, self.ref["yaw"][0]), yaw_rate=np.zeros(n), yaw_acc=np.zeros(n))
        return out


def fly(vehicle, controller: Controller, setpoints: Setpoints, x0: np.ndarray, t0: float, t1: float, mass: float,
        actuation: Actuation = Actuation(), sim_rate_hz: float = 1000.0, logged_position=None,
        max_error_m: float = 2.0, settle_s: float = 0.0) -> Flown:
    """Fly ``vehicle`` from state ``x0`` (plant state, :func:`initial_state`) at time ``t0`` to ``t1`` (s, the
    log's clock) under ``controller`` (reset with ``mass``, kg) along ``setpoints``.

    The controller runs every ``round(sim_rate_hz / controller.rate_hz)`` integration steps; its command is
    held.  ``logged_position`` (optional, ``(times, positions (n, 3))``: the logged flight): the simulation
    stops as lost where it is ``max_error_m`` from it (also when non-finite or upside down).  ``settle_s``: the
    controller first flies this vehicle for that long from ``x0`` with the setpoint of ``t0`` held, so that its
    integrators hold what the vehicle needs to hover (as a flight's do when its log starts in the air); the
    plant then starts again from ``x0``, the controller's state kept."""
    controller.reset(vehicle, mass)
    sim_rate_hz = integration_rate(sim_rate_hz, float(controller.rate_hz),
                                   float(true_params(vehicle, list(vehicle.effects))[P_DELAY]))
    if settle_s > 0:
        _loop(vehicle, controller, Held(setpoints, t0), x0, t0 - settle_s, t0, actuation, sim_rate_hz, None, np.inf)
    return _loop(vehicle, controller, setpoints, x0, t0, t1, actuation, sim_rate_hz, logged_position, max_error_m)


def integration_rate(rate_hz: float, controller_hz: float, delay_s: float) -> float:
    """``rate_hz``, or where a model's actuator delay is shorter than its step, the lowest multiple of the
    controller's rate whose step is at most the delay: the delayed rotor map reads speeds of past steps only
    (a refined model's delay may be a fraction of a millisecond).  The flown times show the step taken."""
    if not 0.0 < delay_s < 1.0 / rate_hz:
        return rate_hz
    k = max(1, math.ceil(1.0 / (delay_s * controller_hz)))
    while 1.0 / (k * controller_hz) > delay_s:
        k += 1
    return k * controller_hz


def _loop(vehicle, controller, setpoints, x0, t0, t1, actuation, sim_rate_hz, logged_position, max_error_m) -> Flown:
    every = max(1, int(round(sim_rate_hz / float(controller.rate_hz))))
    dt = 1.0 / sim_rate_hz
    n = int(math.floor((t1 - t0) / dt + 1e-9))
    P = true_params(vehicle, list(vehicle.effects))
    r = P[P_MARKER].copy()
    hist = history_buffer(P, dt, x0[X_ROTORS])
    u0 = x0[X_ROTORS].copy()
    lo, hi = vehicle.rotor_speed_min, vehicle.rotor_speed_max
    ticks = t0 + dt * np.arange(0, n + 1, every)
    ref = setpoints.at(ticks)
    t = t0 + dt * np.arange(n + 1)
    near = None
    if logged_position is not None:
        tl, pl = logged_position
        ok = np.isfinite(pl).all(axis=1)
        near = np.stack([np.interp(t, tl[ok], pl[ok, i]) for i in range(3)], axis=1)
    if type(controller) is LeeController:  # the built-in controller: the whole loop compiled (same numbers)
        a = _actuation_vector(actuation, vehicle)
        X, TP, Ucmd, thrust, duties, m, lost = _fly_lee(
            x0, P, controller._G, controller._integ, every, dt, n, ref["p"], ref["v"], ref["a"], ref["j"], ref["yaw"],
            ref["yaw_rate"], a, vehicle.rotors.inverse.copy(), lo, hi, near if near is not None else np.zeros((0, 3)),
            max_error_m, hist, u0, r)
        diverged = float(t[m]) if lost else None
        return Flown(t[:m], TP[:m, X_POS], TP[:m, X_VEL], X[:m, X_QUAT], X[:m, X_RATE], X[:m, X_ROTORS], thrust[:m],
                     duties[:m], X[:m], Ucmd[:m], diverged)
    return _loop_in_python(vehicle, controller, actuation, x0, P, hist, (lo, hi), every, dt, t, ref, near, max_error_m)


def _loop_in_python(vehicle, controller, actuation, x0, P, hist, limits, every: int, dt: float, t, ref, near,
                    max_error_m) -> Flown:
    """:func:`_loop` for any controller: the controller called in Python at its rate, the plant stepped compiled."""
    lo, hi = limits
    n = len(t) - 1
    r = P[P_MARKER].copy()
    u0 = x0[X_ROTORS].copy()
    zero = np.zeros(3)
    X = np.full((n + 1, N_X), np.nan)
    TP = np.full((n + 1, X_QUAT.start), np.nan)  # the tracked point's p, v
    Ucmd = np.full((n + 1, 4), np.nan)
    thrust = np.full(n + 1, np.nan)
    duties = np.full((n + 1, 4), np.nan)
    x = x0.copy()
    u_cmd = u0.copy()
    T, D = np.nan, np.full(4, np.nan)
    diverged = None
    for k in range(n + 1):
        pv = tracked_pv(x, r)
        if k % every == 0:
            j = k // every
            state = State(np.array(pv[X_POS]), np.array(pv[X_VEL]), x[X_QUAT].copy(), x[X_RATE].copy())
            sp = Setpoint(ref["p"][j], ref["v"][j], ref["a"][j], ref["j"][j], ref["s"][j], float(ref["yaw"][j]),
                          float(ref["yaw_rate"][j]), float(ref["yaw_acc"][j]))
            cmd = controller(float(t[k]), state, sp)
            raw, d = actuation.speeds(cmd, vehicle)
            u_cmd = np.clip(raw, lo, hi)
            T = float(cmd.thrust) if cmd.thrust is not None else np.nan
            D = d if d is not None else np.full(4, np.nan)
        X[k] = x
        TP[k] = pv
        Ucmd[k] = u_cmd
        thrust[k] = T
        duties[k] = D
        lost = _lost(x, pv, near[k] if near is not None else None, max_error_m)
        if lost:
            diverged = float(t[k])
            break
        if k < n:
            x = rk4_step(x, u_cmd, P, zero, zero, dt, hist, u0, k)
    m = k + 1 if diverged is None else k
    return Flown(t[:m], TP[:m, X_POS], TP[:m, X_VEL], X[:m, X_QUAT], X[:m, X_RATE], X[:m, X_ROTORS], thrust[:m],
                 duties[:m], X[:m], Ucmd[:m], diverged)


# actuation vector of the compiled loop: [kind (0 ideal, 1 crazyflie), map (0 fit, 1 firmware), arm, t2t, vbat,
# C_T, d00, d10, d01, d20, d11, a1..a4, b1..b4]
A_KIND, A_MAP, A_ARM, A_T2T, A_VBAT, A_CT, A_D, A_A, A_B, N_A = 0, 1, 2, 3, 4, 5, 6, 11, 15, 19


def _actuation_vector(actuation: Actuation, vehicle) -> np.ndarray:
    a = np.zeros(N_A)
    a[A_CT] = vehicle.thrust_coeff
    if actuation.mixer is not None:
        mx, mm = actuation.mixer, actuation.motor_map
        a[A_KIND], a[A_MAP] = 1.0, 0.0 if mm.kind == "fit" else 1.0
        a[A_ARM], a[A_T2T], a[A_VBAT] = mx.arm_length, mx.thrust_to_torque, actuation.vbat
        a[A_D:A_D + 5] = mx.pwm.vector()
        if mm.kind == "fit":
            a[A_A:A_A + 4], a[A_B:A_B + 4] = mm.a, mm.b
    return a


@nb.njit(cache=True)
def ideal_speeds(Binv, T, tau):
    """Rotor speeds of a thrust and torques through the inverse rotor map (negative squares to 0), in index
    order."""
    u = np.empty(4)
    for i in range(4):
        u2 = Binv[i, 0] * T + Binv[i, 1] * tau[0] + Binv[i, 2] * tau[1] + Binv[i, 3] * tau[2]
        u[i] = math.sqrt(max(u2, 0.0))
    return u


@nb.njit(cache=True)
def _speeds(T, tau, a, Binv):
    """Rotor-speed command of a thrust and torques (:meth:`Actuation.speeds`, compiled) and the duties."""
    u = np.empty(4)
    d = np.full(4, np.nan)
    if a[A_KIND] == 0.0:
        return ideal_speeds(Binv, T, tau), d
    d = _duties(T, tau, a[A_ARM], a[A_T2T], a[A_D:A_D + 5], a[A_VBAT])
    v = a[A_VBAT]
    for i in range(4):
        if a[A_MAP] == 0.0:
            u[i] = a[A_A + i] + a[A_B + i] * d[i]
        else:
            b = a[A_D + 1] + a[A_D + 4] * v
            c = a[A_D] + a[A_D + 2] * v - d[i]
            d20 = a[A_D + 3]
            f = -c / b if d20 == 0.0 else (-b + math.sqrt(max(b * b - 4.0 * d20 * c, 0.0))) / (2.0 * d20)
            u[i] = math.sqrt(max(f, 0.0) / GRAMS_PER_NEWTON / a[A_CT])
    return u, d


@nb.njit(cache=True)
def _fly_lee(x0, P, G, integ, every, dt, n, rp, rv, ra, rj, ryaw, ryr, a, Binv, lo, hi, near, max_err, hist, u0, r):
    """:func:`fly`'s loop with the Lee controller, compiled: (X, TP, Ucmd, thrust, duties, steps, lost); the
    controller's integrators ``integ`` carried on in place."""
    X = np.full((n + 1, N_X), np.nan)
    TP = np.full((n + 1, X_QUAT.start), np.nan)  # the tracked point's p, v
    Ucmd = np.full((n + 1, 4), np.nan)
    thrust = np.full(n + 1, np.nan)
    duties = np.full((n + 1, 4), np.nan)
    zero = np.zeros(3)
    p, v, q, w = X_POS.start, X_VEL.start, X_QUAT.start, X_RATE.start
    x = x0.copy()
    u_cmd = u0.copy()
    T = np.nan
    D = np.full(4, np.nan)
    for k in range(n + 1):
        pv = tracked_pv(x, r)
        if k % every == 0:
            j = k // every
            R = quat_to_R(x[X_QUAT])
            T, tau, _, _ = lee_step(np.array([pv[p], pv[p + 1], pv[p + 2]]), np.array([pv[v], pv[v + 1], pv[v + 2]]), R,
                                    x[X_RATE].copy(), rp[j], rv[j], ra[j], rj[j], ryaw[j], ryr[j], G, integ)
            raw, D = _speeds(T, tau, a, Binv)
            for i in range(4):
                u_cmd[i] = min(max(raw[i], lo), hi)
        X[k] = x
        for i in range(X_QUAT.start):
            TP[k, i] = pv[i]
        Ucmd[k] = u_cmd
        thrust[k] = T
        duties[k] = D
        s = x[p] + x[p + 1] + x[p + 2] + x[q] + x[q + 1] + x[q + 2] + x[q + 3] + x[w] + x[w + 1] + x[w + 2]
        lost = not math.isfinite(s) or 1.0 - 2.0 * (x[q + 1] ** 2 + x[q + 2] ** 2) < UPSIDE_DOWN
        if not lost and near.shape[0] > 0:
            e = math.sqrt((pv[p] - near[k, 0]) ** 2 + (pv[p + 1] - near[k, 1]) ** 2 + (pv[p + 2] - near[k, 2]) ** 2)
            lost = e > max_err
        if lost:
            return X, TP, Ucmd, thrust, duties, k, True
        if k < n:
            x = rk4_step(x, u_cmd, P, zero, zero, dt, hist, u0, k)
    return X, TP, Ucmd, thrust, duties, n + 1, False


def _lost(x, pv, ref, max_error_m) -> bool:
    p, q, w = X_POS.start, X_QUAT.start, X_RATE.start
    if not (math.isfinite(x[p] + x[p + 1] + x[p + 2] + x[q] + x[q + 1] + x[q + 2] + x[q + 3] + x[w] + x[w + 1]
                          + x[w + 2])):
        return True
    if 1.0 - 2.0 * (x[q + 1] ** 2 + x[q + 2] ** 2) < UPSIDE_DOWN:
        return True
    return ref is not None and math.dist(pv[X_POS], ref) > max_error_m


def _acting(X, P, dt) -> np.ndarray:
    """The rotor speeds acting on the body: the motor state, or with an actuator delay the delayed one."""
    u = X[:, X_ROTORS].copy()
    d = P[P_DELAY] / dt
    if d > 0:
        s = np.arange(len(X)) - d
        for i in range(4):
            u[:, i] = np.interp(s, np.arange(len(X)), X[:, X_ROTORS.start + i], left=X[0, X_ROTORS.start + i])
    return u


def accelerations(flown: Flown, vehicle) -> tuple[np.ndarray, np.ndarray]:
    """World acceleration of the CG and body angular acceleration at each step (TRUE physics)."""
    P = true_params(vehicle, list(vehicle.effects))
    zero = np.zeros(3)
    dt = float(flown.t[1] - flown.t[0]) if len(flown.t) > 1 else 1.0
    u = _acting(flown.x, P, dt)
    a = np.empty((len(flown.t), 3))
    al = np.empty((len(flown.t), 3))
    for k in range(len(flown.t)):
        a[k], al[k] = plant_accels(flown.x[k], u[k], P, zero, zero)
    return a, al
