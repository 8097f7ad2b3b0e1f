"""The rigid-body plant shared by ``qr synth`` and the simulation study.

RK4 with first-order rotor dynamics ``u̇ = (u_cmd - u) / τ_m``; the quaternion is
renormalised after every step.  Catalog effects act in this TRUE plant through
their physics (true mass and inertia, scaled rotor thrust, a delayed rotor
map, a displaced tracked point, added forces and torques), never through the
catalog's own formulas, so tests comparing residuals with the catalog terms
check two independent derivations.

State ``x`` (17): ``p`` (3, world, CG), ``v`` (3, world), ``q`` (4, scalar first),
``ω`` (3, body), ``u`` (4, rotor speeds in the vehicle unit).  Kernels are
compiled with numba: a 90 s flight at 1 kHz takes well under a second.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ..frames_compiled import cross, quat_to_R

from ..frames import G

# ---- parameter vector of the TRUE plant (one place for its layout) ----------
P_MASS, P_J, P_B, P_SCALE, P_CQGAIN, P_TAU, P_DELAY = 0, 1, 4, 20, 24, 25, 26
P_LIN, P_QUAD, P_RDRAG, P_WIND, P_BBIAS, P_GE, P_GZ = 27, 30, 33, 34, 37, 40, 41
P_CG, P_TBIAS, P_FLAP, P_MARKER = 42, 44, 47, 48
P_REM_ON, P_UHOVER, P_REM = 51, 52, 53  # a learned torque remainder (qr.torque_remainder): flag, u_hover, W (3 x 11)
N_P = 53 + 33
N_X = 17
MIN_GROUND_HEIGHT = 0.02  # m; keeps k T / p_z² finite if a crash is simulated


def true_params(vehicle, effects: list[dict] | None = None) -> np.ndarray:
    """Pack the vehicle and catalog effects into the plant's parameter vector."""
    P = np.zeros(N_P)
    P[P_MASS] = vehicle.mass
    P[P_J:P_J + 3] = vehicle.inertia
    P[P_B:P_B + 16] = vehicle.rotors.matrix.ravel()
    P[P_SCALE:P_SCALE + 4] = 1.0
    P[P_CQGAIN] = 1.0
    P[P_TAU] = vehicle.motor_time_constant
    P[P_GZ] = vehicle.ground_z
    P[P_UHOVER] = vehicle.hover_speed
    W = vehicle.raw.get("torque_remainder")
    if W:
        P[P_REM_ON] = 1.0
        P[P_REM:P_REM + 33] = np.asarray(W["weights"], float).ravel()
    for e in effects or []:
        n, k = e["name"], e["parameters"]
        if n == "linear_drag":
            P[P_LIN:P_LIN + 3] += [k["kx"], k["ky"], k["kz"]]
        elif n == "quadratic_drag":
            P[P_QUAD:P_QUAD + 3] += [k["cx"], k["cy"], k["cz"]]
        elif n == "rotor_drag":
            P[P_RDRAG] += k["k"]
        elif n == "wind_force":
            P[P_WIND:P_WIND + 3] += [k["fx"], k["fy"], k["fz"]]
        elif n == "body_force_bias":
            P[P_BBIAS:P_BBIAS + 3] += [k["bx"], k["by"], k["bz"]]
        elif n == "thrust_gain":
            P[P_SCALE:P_SCALE + 4] *= k["gain"]
        elif n == "mass_error":
            P[P_MASS] += k["dm"]
        elif n == "ground_effect":
            P[P_GE] += k["k"]
        elif n == "motor_imbalance":
            P[P_SCALE:P_SCALE + 4] *= 1.0 + np.array([k["d1"], k["d2"], k["d3"], k["d4"]])
        elif n == "cg_offset":
            P[P_CG:P_CG + 2] += [k["rx"], k["ry"]]
        elif n == "torque_bias":
            P[P_TBIAS:P_TBIAS + 3] += [k["tx"], k["ty"], k["tz"]]
        elif n == "yaw_torque_gain":
            P[P_CQGAIN] *= k["gain"]
        elif n == "inertia_error":
            P[P_J:P_J + 3] += [k["dJxx"], k["dJyy"], k["dJzz"]]
        elif n == "actuator_delay":
            P[P_DELAY] += k["delay_s"]
        elif n == "marker_offset":
            P[P_MARKER:P_MARKER + 3] += [k["rx"], k["ry"], k["rz"]]
        elif n == "blade_flapping":
            P[P_FLAP] += k["k"]
        else:  # pragma: no cover - the catalog and this list must agree
            raise KeyError(n)
    if P[P_MASS] <= 0 or np.any(P[P_J:P_J + 3] <= 0):
        raise ValueError("effects make the true mass or inertia non-positive")
    return P


@nb.njit(cache=True)
def plant_accels(x, u_eff, P, f_ext, tau_ext):
    """World acceleration of the CG and body angular acceleration (TRUE physics)."""
    R = quat_to_R(x[6:10])
    v = x[3:6]
    w = x[10:13]
    v_b = R.T @ v
    # rotor wrench with per-rotor thrust scale and yaw-torque gain
    T = 0.0
    Gam = np.zeros(3)
    omega_sum = 0.0
    for i in range(4):
        u2 = u_eff[i] * u_eff[i]
        s = P[P_SCALE + i]
        T += P[P_B + 0 * 4 + i] * s * u2
        Gam[0] += P[P_B + 1 * 4 + i] * s * u2
        Gam[1] += P[P_B + 2 * 4 + i] * s * u2
        Gam[2] += P[P_B + 3 * 4 + i] * P[P_CQGAIN] * u2
        omega_sum += u_eff[i]
    f_b = np.zeros(3)
    f_b[2] = T
    for j in range(3):
        f_b[j] += -P[P_LIN + j] * v_b[j] - P[P_QUAD + j] * abs(v_b[j]) * v_b[j] + P[P_BBIAS + j] + f_ext[j]
    f_b[0] -= P[P_RDRAG] * omega_sum * v_b[0]
    f_b[1] -= P[P_RDRAG] * omega_sum * v_b[1]
    if P[P_GE] != 0.0:
        r = P[P_MARKER:P_MARKER + 3]
        h = x[2] + R[2, 0] * r[0] + R[2, 1] * r[1] + R[2, 2] * r[2] - P[P_GZ]
        h = max(h, MIN_GROUND_HEIGHT)
        f_b[2] += P[P_GE] * T / (h * h)
    m = P[P_MASS]
    a = (R @ f_b) / m
    for j in range(3):
        a[j] += P[P_WIND + j] / m
    a[2] -= G
    J = P[P_J:P_J + 3]
    tau = Gam.copy()
    tau[0] += -P[P_CG + 1] * T + P[P_TBIAS + 0] + P[P_FLAP] * v_b[1] + tau_ext[0]
    tau[1] += P[P_CG + 0] * T + P[P_TBIAS + 1] - P[P_FLAP] * v_b[0] + tau_ext[1]
    tau[2] += P[P_TBIAS + 2] + tau_ext[2]
    if P[P_REM_ON] != 0.0:
        f = np.empty(11)
        f[0:3] = v_b
        f[3:6] = w
        for i in range(4):
            f[6 + i] = (u_eff[i] / P[P_UHOVER]) ** 2 - 1.0
        f[10] = 1.0
        for k in range(3):
            for j in range(11):
                tau[k] += P[P_REM + 11 * k + j] * f[j]
    Jw = J * w
    tau += cross(Jw, w)
    alpha = tau / J
    return a, alpha


@nb.njit(cache=True)
def rigid_body_deriv(x, u_eff, P, f_ext, tau_ext, dx):
    """Derivatives of p, v, q, ω (``dx[0:13]``) with the rotor speeds ``u_eff`` acting."""
    a, alpha = plant_accels(x, u_eff, P, f_ext, tau_ext)
    dx[0:3] = x[3:6]
    dx[3:6] = a
    q = x[6:10]
    w = x[10:13]
    # q̇ = ½ q ⊗ [0, ω]
    dx[6] = 0.5 * (-q[1] * w[0] - q[2] * w[1] - q[3] * w[2])
    dx[7] = 0.5 * (q[0] * w[0] + q[2] * w[2] - q[3] * w[1])
    dx[8] = 0.5 * (q[0] * w[1] + q[3] * w[0] - q[1] * w[2])
    dx[9] = 0.5 * (q[0] * w[2] + q[1] * w[1] - q[2] * w[0])
    dx[10:13] = alpha


@nb.njit(cache=True)
def deriv(x, u_cmd, u_eff, P, f_ext, tau_ext):
    dx = np.empty(N_X)
    rigid_body_deriv(x, u_eff, P, f_ext, tau_ext, dx)
    dx[13:17] = (u_cmd - x[13:17]) / P[P_TAU]
    return dx


@nb.njit(cache=True)
def delayed_speeds(hist, u0, k, c, d_steps):
    """Rotor speeds at step time ``k + c - d_steps`` from a ring buffer (row ``j % M`` = step j)."""
    s = k + c - d_steps
    if s <= 0.0:
        return u0.copy()
    j = int(math.floor(s))
    frac = s - j
    M = hist.shape[0]
    if frac == 0.0:
        return hist[j % M].copy()
    return (1.0 - frac) * hist[j % M] + frac * hist[(j + 1) % M]


@nb.njit(cache=True)
def rk4_step(x, u_cmd, P, f_ext, tau_ext, dt, hist, u0, k):
    """One RK4 step from step ``k``; ``hist`` holds past rotor speeds when the plant has a delay."""
    d_steps = P[P_DELAY] / dt
    if d_steps > 0.0:
        ue0 = delayed_speeds(hist, u0, k, 0.0, d_steps)
        ue1 = delayed_speeds(hist, u0, k, 0.5, d_steps)
        ue2 = delayed_speeds(hist, u0, k, 1.0, d_steps)
        k1 = deriv(x, u_cmd, ue0, P, f_ext, tau_ext)
        k2 = deriv(x + 0.5 * dt * k1, u_cmd, ue1, P, f_ext, tau_ext)
        k3 = deriv(x + 0.5 * dt * k2, u_cmd, ue1, P, f_ext, tau_ext)
        x4 = x + dt * k3
        k4 = deriv(x4, u_cmd, ue2, P, f_ext, tau_ext)
    else:
        k1 = deriv(x, u_cmd, x[13:17], P, f_ext, tau_ext)
        x2 = x + 0.5 * dt * k1
        k2 = deriv(x2, u_cmd, x2[13:17], P, f_ext, tau_ext)
        x3 = x + 0.5 * dt * k2
        k3 = deriv(x3, u_cmd, x3[13:17], P, f_ext, tau_ext)
        x4 = x + dt * k3
        k4 = deriv(x4, u_cmd, x4[13:17], P, f_ext, tau_ext)
    xn = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    n = math.sqrt(xn[6] ** 2 + xn[7] ** 2 + xn[8] ** 2 + xn[9] ** 2)
    xn[6:10] /= n
    if d_steps > 0.0:
        hist[(k + 1) % hist.shape[0]] = xn[13:17]
    return xn


def history_buffer(P: np.ndarray, dt: float, u0: np.ndarray) -> np.ndarray:
    """Ring buffer for the delayed rotor map (one row when there is no delay)."""
    d = P[P_DELAY]
    if d > 0 and d < dt:
        raise ValueError(f"actuator delay {d} s is below the integration step {dt} s; "
                         "raise the integration rate or the delay")
    M = int(math.ceil(d / dt)) + 4 if d > 0 else 1
    h = np.empty((M, 4))
    h[:] = u0
    return h


@nb.njit(cache=True)
def tracked_point(x, a, alpha, r):
    """Position, velocity, acceleration (world) of the point at body offset ``r`` from the CG."""
    R = quat_to_R(x[6:10])
    w = x[10:13]
    p = x[0:3] + R @ r
    v = x[3:6] + R @ cross(w, r)
    acc = a + R @ (cross(alpha, r) + cross(w, cross(w, r)))
    return p, v, acc


def hover_state(vehicle, p0, yaw0=0.0) -> np.ndarray:
    x = np.zeros(N_X)
    x[0:3] = p0
    x[6:10] = [math.cos(yaw0 / 2), 0.0, 0.0, math.sin(yaw0 / 2)]
    x[13:17] = vehicle.hover_speed
    return x
