"""The rigid-body plant shared by ``qr synth``, the simulation study, the rollout and the replay: RK4 with
first-order rotor dynamics, the quaternion renormalised after every step; catalog effects act through their
physics (true mass and inertia, scaled thrust, delayed rotor map, displaced tracked point, added wrench),
never through the catalog's own formulas, so tests comparing the two check independent derivations.
State and parameters: the slots of :mod:`qr.plant_state`; compiled with numba.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ..frames import G
from ..frames_compiled import R_entries, cross, matvec, quat_to_R
from ..plant_state import (NET_DEPTH, NET_INPUTS, NET_RELU, NET_SPEED, N_NET_HEAD, N_P, N_RB, N_X, P_B, P_BBIAS, P_CG,
                           P_CQGAIN, P_DELAY, P_FLAP, P_FLAP_PITCH, P_GE, P_GZ, P_HUB, P_J, P_LIN, P_MARKER, P_MASS,
                           P_QUAD, P_RDM, P_RDRAG, P_REM, P_REM_ON, P_RES_ON, P_ROTOR_J, P_SCALE, P_TAU, P_TBIAS,
                           P_TLIFT, P_UHOVER, P_WIND, P_YAW_GAIN, X_POS, X_QUAT, X_RATE, X_ROTORS, X_VEL)

RAD_S_PER_UNIT = {"rpm": 2 * math.pi / 60.0, "rad_s": 1.0}
MIN_GROUND_HEIGHT = 0.02  # m; keeps k T / p_z² finite if a crash is simulated


def true_params(vehicle, effects: list[dict] | None = None, residual: bool = True) -> np.ndarray:
    """Pack the vehicle and catalog effects into the plant's parameter vector (``residual``: with the
    vehicle's learned wrench, if it has one, appended after ``N_P``)."""
    P = _vehicle_params(vehicle)
    for e in effects or []:
        _add_effect(P, e["name"], e["parameters"])
    if P[P_MASS] <= 0 or np.any(P[P_J] <= 0):
        raise ValueError("effects make the true mass or inertia non-positive")
    net = getattr(vehicle, "residual", None)
    if residual and net is not None:
        from ..residual import pack

        P[P_RES_ON] = 1.0
        P = np.concatenate([P, pack(net)])
    return P


def _vehicle_params(vehicle) -> np.ndarray:
    """The parameter vector of the vehicle file alone (no effect, no learned wrench)."""
    P = np.zeros(N_P)
    P[P_MASS] = vehicle.mass
    P[P_J] = vehicle.inertia
    P[P_B] = vehicle.rotors.matrix.ravel()
    P[P_SCALE] = 1.0
    P[P_CQGAIN] = 1.0
    P[P_TAU] = vehicle.motor_time_constant
    P[P_GZ] = vehicle.ground_z
    P[P_UHOVER] = vehicle.hover_speed
    for i, (x, y) in enumerate(vehicle.rotors.positions[:4]):
        P[P_HUB.start + 3 * i:P_HUB.start + 3 * i + 3] = x, y, vehicle.hub_z
    P[P_FLAP_PITCH] = vehicle.flapping_pitch_ratio
    P[P_ROTOR_J] = vehicle.rotor_inertia * RAD_S_PER_UNIT[vehicle.rotor_speed_unit]
    P[P_YAW_GAIN] = vehicle.rotor_torque_gains
    W = vehicle.raw.get("torque_remainder")
    if W:
        P[P_REM_ON] = 1.0
        P[P_REM] = np.asarray(W["weights"], float).ravel()
    return P


def _add_effect(P: np.ndarray, n: str, k: dict) -> None:
    """Catalog effect ``n`` with parameters ``k`` added into ``P`` (gains multiply, offsets add)."""
    if n == "linear_drag":
        P[P_LIN] += [k["kx"], k["ky"], k["kz"]]
    elif n == "quadratic_drag":
        P[P_QUAD] += [k["cx"], k["cy"], k["cz"]]
    elif n == "rotor_drag":
        P[P_RDRAG] += k["k"]
    elif n == "wind_force":
        P[P_WIND] += [k["fx"], k["fy"], k["fz"]]
    elif n == "body_force_bias":
        P[P_BBIAS] += [k["bx"], k["by"], k["bz"]]
    elif n == "thrust_gain":
        P[P_SCALE] *= k["gain"]
    elif n == "mass_error":
        P[P_MASS] += k["dm"]
    elif n == "ground_effect":
        P[P_GE] += k["k"]
    elif n == "motor_imbalance":
        d = np.array([k["d1"], k["d2"], k["d3"], k["d4"]])
        P[P_SCALE] *= 1.0 + d
        P[P_YAW_GAIN] *= 1.0 + d - d.mean()  # its drag torque with its thrust, relative to the others (effects)
    elif n == "cg_offset":
        P[P_CG] += [k["rx"], k["ry"]]
    elif n == "torque_bias":
        P[P_TBIAS] += [k["tx"], k["ty"], k["tz"]]
    elif n == "yaw_torque_gain":
        P[P_CQGAIN] *= k["gain"]
    elif n == "inertia_error":
        P[P_J] += [k["dJxx"], k["dJyy"], k["dJzz"]]
    elif n == "actuator_delay":
        P[P_DELAY] += k["delay_s"]
    elif n == "marker_offset":
        P[P_MARKER] += [k["rx"], k["ry"], k["rz"]]
    elif n == "blade_flapping":
        P[P_FLAP] += k["k"]
    elif n == "rotor_drag_moment":
        P[P_RDM] += k["k"]
    elif n == "translational_lift":
        P[P_TLIFT] += k["k"]
    else:  # pragma: no cover - the catalog and this list must agree
        raise KeyError(n)


@nb.njit(cache=True)
def residual_wrench(P, vb0, vb1, vb2, wx, wy, wz, g0, g1, g2, u):
    """The learned wrench of ``qr.residual`` (body force, N, and torque, N m) from the network packed at
    ``P[N_P:]`` (:func:`qr.residual.pack`): features, normalisation, the layers, the output scale."""
    o = N_P
    speed = P[o + NET_SPEED]
    relu = P[o + NET_RELU] != 0.0
    L = int(P[o + NET_DEPTH])
    dims = o + N_NET_HEAD  # d_0 … d_L
    width = 0
    for k in range(L + 1):
        width = max(width, int(P[dims + k]))
    z = np.empty(width)
    y = np.empty(width)
    n = 0
    flags = o + NET_INPUTS.start  # v_b, ω, g_b, u, u² (qr.residual.ORDER)
    if P[flags] != 0.0:
        z[0], z[1], z[2] = vb0, vb1, vb2
        n = 3
    if P[flags + 1] != 0.0:
        z[n], z[n + 1], z[n + 2] = wx, wy, wz
        n += 3
    if P[flags + 2] != 0.0:
        z[n], z[n + 1], z[n + 2] = g0, g1, g2
        n += 3
    if P[flags + 3] != 0.0:
        for i in range(4):
            z[n + i] = u[i] / speed
        n += 4
    if P[flags + 4] != 0.0:
        for i in range(4):
            s = u[i] / speed
            z[n + i] = s * s
        n += 4
    a = dims + L + 1
    for i in range(n):
        z[i] = (z[i] - P[a + i]) / P[a + n + i]
    a += 2 * n
    for k in range(L):
        d_in, d_out = int(P[dims + k]), int(P[dims + k + 1])
        for r in range(d_out):
            acc = P[a + d_out * d_in + r]
            base = a + r * d_in
            for c in range(d_in):
                acc += P[base + c] * z[c]
            if k < L - 1:
                acc = max(acc, 0.0) if relu else math.tanh(acc)
            y[r] = acc
        a += d_out * d_in + d_out
        z, y = y, z
    return (z[0] * P[a], z[1] * P[a + 1], z[2] * P[a + 2], z[3] * P[a + 3], z[4] * P[a + 4], z[5] * P[a + 5])


@nb.njit(cache=True, inline="always")
def _accels(x, u_eff, P, f_ext, tau_ext):
    """World acceleration of the CG and body angular acceleration (TRUE physics), as six scalars.

    Written out in scalars: the rollout and the simulation call it four times per RK4 step, millions
    of times, and small temporary arrays (and 3 x 3 products through BLAS) cost ten times the
    arithmetic."""
    q, v, w = X_QUAT.start, X_VEL.start, X_RATE.start
    R00, R01, R02, R10, R11, R12, R20, R21, R22 = R_entries(x[q], x[q + 1], x[q + 2], x[q + 3])
    vx, vy, vz = x[v], x[v + 1], x[v + 2]
    wx, wy, wz = x[w], x[w + 1], x[w + 2]
    vb0 = R00 * vx + R10 * vy + R20 * vz  # v_b = R^T v
    vb1 = R01 * vx + R11 * vy + R21 * vz
    vb2 = R02 * vx + R12 * vy + R22 * vz
    # rotor wrench with per-rotor thrust scale and yaw-torque gain
    T = 0.0
    G0 = 0.0
    G1 = 0.0
    G2 = 0.0
    omega_sum = 0.0
    B = P_B.start  # rows: thrust, roll, pitch, yaw torque per u²
    for i in range(4):
        u2 = u_eff[i] * u_eff[i]
        sc = P[P_SCALE.start + i]
        T += P[B + 0 * 4 + i] * sc * u2
        G0 += P[B + 1 * 4 + i] * sc * u2
        G1 += P[B + 2 * 4 + i] * sc * u2
        G2 += P[B + 3 * 4 + i] * P[P_CQGAIN] * P[P_YAW_GAIN.start + i] * u2
        omega_sum += u_eff[i]
    lin, quad, bias = P_LIN.start, P_QUAD.start, P_BBIAS.start
    f0 = -P[lin] * vb0 - P[quad] * abs(vb0) * vb0 + P[bias] + f_ext[0] - P[P_RDRAG] * omega_sum * vb0
    f1 = -P[lin + 1] * vb1 - P[quad + 1] * abs(vb1) * vb1 + P[bias + 1] + f_ext[1] \
        - P[P_RDRAG] * omega_sum * vb1
    f2 = T - P[lin + 2] * vb2 - P[quad + 2] * abs(vb2) * vb2 + P[bias + 2] + f_ext[2]
    cx, cy = P[P_CG.start], P[P_CG.start + 1]
    if P[P_GE] != 0.0:
        mk = P_MARKER.start
        h = x[X_POS.start + 2] + R20 * P[mk] + R21 * P[mk + 1] + R22 * P[mk + 2] - P[P_GZ]
        h = max(h, MIN_GROUND_HEIGHT)
        f2 += P[P_GE] * T / (h * h)
    t0 = t1 = t2 = 0.0
    if P[P_RDM] != 0.0 or P[P_TLIFT] != 0.0:
        # at each hub r_i (from the CG: the layout, the hub height, less a CG offset), airspeed w = v_b + ω × r_i:
        # the rotor drag's H-force -k u_i [w_x, w_y, 0] acts there (its moment about the CG), and the rotor's
        # thrust grows by k_lift (w_x² + w_y²)
        for i in range(4):
            hub = P_HUB.start + 3 * i
            rx = P[hub] - cx
            ry = P[hub + 1] - cy
            rz = P[hub + 2]
            hx = vb0 + wy * rz - wz * ry
            hy = vb1 + wz * rx - wx * rz
            Hx = -P[P_RDM] * u_eff[i] * hx
            Hy = -P[P_RDM] * u_eff[i] * hy
            lift = P[P_TLIFT] * (hx * hx + hy * hy)
            f2 += lift
            t0 += -rz * Hy + ry * lift
            t1 += rz * Hx - rx * lift
            t2 += rx * Hy - ry * Hx
    r0 = r1 = r2 = r3 = r4 = r5 = 0.0
    if P[P_RES_ON] != 0.0:
        r0, r1, r2, r3, r4, r5 = residual_wrench(P, vb0, vb1, vb2, wx, wy, wz, -R20, -R21, -R22, u_eff)
        f0 += r0
        f1 += r1
        f2 += r2
    m = P[P_MASS]
    wind, tb = P_WIND.start, P_TBIAS.start
    ax = (R00 * f0 + R01 * f1 + R02 * f2 + P[wind]) / m
    ay = (R10 * f0 + R11 * f1 + R12 * f2 + P[wind + 1]) / m
    az = (R20 * f0 + R21 * f1 + R22 * f2 + P[wind + 2]) / m - G
    t0 += G0 - cy * T + P[tb + 0] + P[P_FLAP] * vb1 + tau_ext[0]
    t1 += G1 + cx * T + P[tb + 1] - P[P_FLAP] * P[P_FLAP_PITCH] * vb0 + tau_ext[1]
    t2 += G2 + P[tb + 2] + tau_ext[2]
    if P[P_ROTOR_J] != 0.0:  # the rotors' angular momentum h (body z): the gyroscopic moment -ω × h
        hz = rotor_momentum(u_eff, P)
        t0 -= wy * hz
        t1 += wx * hz
    if P[P_REM_ON] != 0.0:
        for k in range(3):
            base = P_REM.start + 11 * k  # W's row k: v_b, ω, (u_i / u_hover)² − 1, 1
            acc = P[base] * vb0 + P[base + 1] * vb1 + P[base + 2] * vb2 + P[base + 3] * wx \
                + P[base + 4] * wy + P[base + 5] * wz + P[base + 10]
            for i in range(4):
                acc += P[base + 6 + i] * ((u_eff[i] / P[P_UHOVER]) ** 2 - 1.0)
            if k == 0:
                t0 += acc
            elif k == 1:
                t1 += acc
            else:
                t2 += acc
    t0 += r3
    t1 += r4
    t2 += r5
    Jx, Jy, Jz = P[P_J.start], P[P_J.start + 1], P[P_J.start + 2]
    # tau + (J w) x w
    t0 += Jy * wy * wz - Jz * wz * wy
    t1 += Jz * wz * wx - Jx * wx * wz
    t2 += Jx * wx * wy - Jy * wy * wx
    return ax, ay, az, t0 / Jx, t1 / Jy, t2 / Jz


@nb.njit(cache=True, inline="always")
def rotor_momentum(u, P):
    """The rotors' angular momentum along body z (kg m²/s): Σ J_r Ω_i spin_i, a rotor spinning
    counter-clockwise seen from above (spin +1) having the yaw sign −1 (its drag turns the body clockwise)."""
    h = 0.0
    for i in range(4):
        h -= (1.0 if P[P_B.start + 12 + i] > 0.0 else -1.0) * u[i]  # the rotor matrix's yaw row
    return P[P_ROTOR_J] * h


@nb.njit(cache=True)
def rotor_speed_change(x, u_old, u_new, P):
    """In place: the body's yaw rate when the rotors jump from ``u_old`` to ``u_new`` (a zero-order hold's
    step): the motors' torques are internal, so the body takes the rotors' change of angular momentum."""
    if P[P_ROTOR_J] != 0.0:
        x[X_RATE.start + 2] -= (rotor_momentum(u_new, P) - rotor_momentum(u_old, P)) / P[P_J.start + 2]


@nb.njit(cache=True)
def plant_accels(x, u_eff, P, f_ext, tau_ext):
    """World acceleration of the CG and body angular acceleration (TRUE physics)."""
    ax, ay, az, bx, by, bz = _accels(x, u_eff, P, f_ext, tau_ext)
    return np.array([ax, ay, az]), np.array([bx, by, bz])


@nb.njit(cache=True, inline="always")
def rigid_body_deriv(x, u_eff, P, f_ext, tau_ext, dx):
    """Derivatives of p, v, q, ω (``dx[:N_RB]``) with the rotor speeds ``u_eff`` acting."""
    ax, ay, az, bx, by, bz = _accels(x, u_eff, P, f_ext, tau_ext)
    p, v, q, w = X_POS.start, X_VEL.start, X_QUAT.start, X_RATE.start
    dx[p] = x[v]
    dx[p + 1] = x[v + 1]
    dx[p + 2] = x[v + 2]
    dx[v] = ax
    dx[v + 1] = ay
    dx[v + 2] = az
    q0, q1, q2, q3 = x[q], x[q + 1], x[q + 2], x[q + 3]
    w0, w1, w2 = x[w], x[w + 1], x[w + 2]
    # q̇ = ½ q ⊗ [0, ω]
    dx[q] = 0.5 * (-q1 * w0 - q2 * w1 - q3 * w2)
    dx[q + 1] = 0.5 * (q0 * w0 + q2 * w2 - q3 * w1)
    dx[q + 2] = 0.5 * (q0 * w1 + q3 * w0 - q1 * w2)
    dx[q + 3] = 0.5 * (q0 * w2 + q1 * w1 - q2 * w0)
    dx[w] = bx
    dx[w + 1] = by
    dx[w + 2] = bz


@nb.njit(cache=True)
def tracked_pv(x, r):
    """Position and velocity (world) of the tracked point at body offset ``r``: ``p + R r``, ``v + R (ω × r)``
    (the inverse of :func:`cg_from_tracked`)."""
    p, v, q, w = X_POS.start, X_VEL.start, X_QUAT.start, X_RATE.start
    R00, R01, R02, R10, R11, R12, R20, R21, R22 = R_entries(x[q], x[q + 1], x[q + 2], x[q + 3])
    c0 = x[w + 1] * r[2] - x[w + 2] * r[1]
    c1 = x[w + 2] * r[0] - x[w] * r[2]
    c2 = x[w] * r[1] - x[w + 1] * r[0]
    return (x[p] + R00 * r[0] + R01 * r[1] + R02 * r[2], x[p + 1] + R10 * r[0] + R11 * r[1] + R12 * r[2],
            x[p + 2] + R20 * r[0] + R21 * r[1] + R22 * r[2], x[v] + R00 * c0 + R01 * c1 + R02 * c2,
            x[v + 1] + R10 * c0 + R11 * c1 + R12 * c2, x[v + 2] + R20 * c0 + R21 * c1 + R22 * c2)


@nb.njit(cache=True)
def cg_from_tracked(x, r):
    """In place: a state of the tracked point (body offset ``r`` from the CG) → the CG's:
    ``p - R r``, ``v - R (ω × r)``."""
    p, v, q, w = X_POS.start, X_VEL.start, X_QUAT.start, X_RATE.start
    R00, R01, R02, R10, R11, R12, R20, R21, R22 = R_entries(x[q], x[q + 1], x[q + 2], x[q + 3])
    c0 = x[w + 1] * r[2] - x[w + 2] * r[1]
    c1 = x[w + 2] * r[0] - x[w] * r[2]
    c2 = x[w] * r[1] - x[w + 1] * r[0]
    x[p] -= R00 * r[0] + R01 * r[1] + R02 * r[2]
    x[p + 1] -= R10 * r[0] + R11 * r[1] + R12 * r[2]
    x[p + 2] -= R20 * r[0] + R21 * r[1] + R22 * r[2]
    x[v] -= R00 * c0 + R01 * c1 + R02 * c2
    x[v + 1] -= R10 * c0 + R11 * c1 + R12 * c2
    x[v + 2] -= R20 * c0 + R21 * c1 + R22 * c2


@nb.njit(cache=True)
def rigid_body_rk4(x, u0, um, u1, P, dt, frozen, zero, k, xs, xn):
    """One RK4 step of p, v, q, ω (``N_RB`` states) into ``xn``, the rotor speeds ``u0``, ``um``, ``u1`` acting at
    the start, middle and end of the step; ``frozen``: ω held.  ``k`` (4, N_RB) and ``xs`` (N_RB,) are
    scratch: the rollout and the replay take millions of steps, and small arrays cost more than the
    arithmetic.  The quaternion is renormalised."""
    # rotor speeds that change within the step (u0 != u1) hand their angular momentum to the body
    hdot = (rotor_momentum(u1, P) - rotor_momentum(u0, P)) / dt if P[P_ROTOR_J] != 0.0 else 0.0
    w, q = X_RATE.start, X_QUAT.start
    for s in range(4):
        if s > 0:
            c = dt if s == 3 else 0.5 * dt
            for j in range(N_RB):
                xs[j] = x[j] + c * k[s - 1, j]
        else:
            for j in range(N_RB):
                xs[j] = x[j]
        rigid_body_deriv(xs, u0 if s == 0 else (u1 if s == 3 else um), P, zero, zero, k[s])
        k[s, w + 2] -= hdot / P[P_J.start + 2]
        if frozen:
            k[s, w] = k[s, w + 1] = k[s, w + 2] = 0.0
    for j in range(N_RB):
        xn[j] = x[j] + dt / 6.0 * (k[0, j] + 2.0 * k[1, j] + 2.0 * k[2, j] + k[3, j])
    n = math.sqrt(xn[q] ** 2 + xn[q + 1] ** 2 + xn[q + 2] ** 2 + xn[q + 3] ** 2)
    for j in range(q, q + 4):
        xn[j] /= n


@nb.njit(cache=True)
def deriv(x, u_cmd, u_eff, P, f_ext, tau_ext):
    dx = np.empty(N_X)
    rigid_body_deriv(x, u_eff, P, f_ext, tau_ext, dx)
    dx[X_ROTORS] = (u_cmd - x[X_ROTORS]) / P[P_TAU]
    if P[P_ROTOR_J] != 0.0:  # the rotors' speed-up turns the body the other way (their momentum's rate)
        dx[X_RATE.start + 2] -= rotor_momentum(dx[X_ROTORS], P) / P[P_J.start + 2]
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
        k1 = deriv(x, u_cmd, x[X_ROTORS], P, f_ext, tau_ext)
        x2 = x + 0.5 * dt * k1
        k2 = deriv(x2, u_cmd, x2[X_ROTORS], P, f_ext, tau_ext)
        x3 = x + 0.5 * dt * k2
        k3 = deriv(x3, u_cmd, x3[X_ROTORS], P, f_ext, tau_ext)
        x4 = x + dt * k3
        k4 = deriv(x4, u_cmd, x4[X_ROTORS], P, f_ext, tau_ext)
    xn = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    q = X_QUAT.start
    n = math.sqrt(xn[q] ** 2 + xn[q + 1] ** 2 + xn[q + 2] ** 2 + xn[q + 3] ** 2)
    xn[X_QUAT] /= n
    if d_steps > 0.0:
        hist[(k + 1) % hist.shape[0]] = xn[X_ROTORS]
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
    R = quat_to_R(x[X_QUAT])
    w = x[X_RATE]
    p = x[X_POS] + matvec(R, r)
    v = x[X_VEL] + matvec(R, cross(w, r))
    acc = a + matvec(R, cross(alpha, r) + cross(w, cross(w, r)))
    return p, v, acc


def hover_state(vehicle, p0, yaw0=0.0) -> np.ndarray:
    x = np.zeros(N_X)
    x[X_POS] = p0
    x[X_QUAT] = [math.cos(yaw0 / 2), 0.0, 0.0, math.sin(yaw0 / 2)]
    x[X_ROTORS] = vehicle.hover_speed
    return x
