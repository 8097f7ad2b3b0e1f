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

from ..frames_compiled import R_entries, cross, matvec, quat_to_R

from ..frames import G

# ---- parameter vector of the TRUE plant (one place for its layout) ----------
P_MASS, P_J, P_B, P_SCALE, P_CQGAIN, P_TAU, P_DELAY = 0, 1, 4, 20, 24, 25, 26
P_LIN, P_QUAD, P_RDRAG, P_WIND, P_BBIAS, P_GE, P_GZ = 27, 30, 33, 34, 37, 40, 41
P_CG, P_TBIAS, P_FLAP, P_MARKER = 42, 44, 47, 48
P_REM_ON, P_UHOVER, P_REM = 51, 52, 53  # a learned torque remainder (qr.torque_remainder): flag, u_hover, W (3 x 11)
P_RES_ON = 86  # a learned wrench (qr.residual): flag; the network follows at P[N_P:] (qr.residual.pack)
P_RDM, P_TLIFT, P_HUB = 87, 88, 89  # rotor drag's moment k, translational lift k, hubs (x, y, z) x 4 from the layout
N_P = 101
N_X = 17
MIN_GROUND_HEIGHT = 0.02  # m; keeps k T / p_z² finite if a crash is simulated


def true_params(vehicle, effects: list[dict] | None = None, residual: bool = True) -> np.ndarray:
    """Pack the vehicle and catalog effects into the plant's parameter vector (``residual``: with the
    vehicle's learned wrench, if it has one, appended after ``N_P``)."""
    P = np.zeros(N_P)
    P[P_MASS] = vehicle.mass
    P[P_J:P_J + 3] = vehicle.inertia
    P[P_B:P_B + 16] = vehicle.rotors.matrix.ravel()
    P[P_SCALE:P_SCALE + 4] = 1.0
    P[P_CQGAIN] = 1.0
    P[P_TAU] = vehicle.motor_time_constant
    P[P_GZ] = vehicle.ground_z
    P[P_UHOVER] = vehicle.hover_speed
    for i, (x, y) in enumerate(vehicle.rotors.positions[:4]):
        P[P_HUB + 3 * i:P_HUB + 3 * i + 3] = x, y, vehicle.hub_z
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
        elif n == "rotor_drag_moment":
            P[P_RDM] += k["k"]
        elif n == "translational_lift":
            P[P_TLIFT] += k["k"]
        else:  # pragma: no cover - the catalog and this list must agree
            raise KeyError(n)
    if P[P_MASS] <= 0 or np.any(P[P_J:P_J + 3] <= 0):
        raise ValueError("effects make the true mass or inertia non-positive")
    net = getattr(vehicle, "residual", None)
    if residual and net is not None:
        from ..residual import pack

        P[P_RES_ON] = 1.0
        P = np.concatenate([P, pack(net)])
    return P


@nb.njit(cache=True)
def residual_wrench(P, vb0, vb1, vb2, wx, wy, wz, g0, g1, g2, u):
    """The learned wrench of ``qr.residual`` (body force, N, and torque, N m) from the network packed at
    ``P[N_P:]`` (:func:`qr.residual.pack`): features, normalisation, the layers, the output scale."""
    o = N_P
    speed = P[o + 5]
    relu = P[o + 6] != 0.0
    L = int(P[o + 7])
    width = 0
    for k in range(L + 1):
        width = max(width, int(P[o + 8 + k]))
    z = np.empty(width)
    y = np.empty(width)
    n = 0
    if P[o] != 0.0:
        z[0], z[1], z[2] = vb0, vb1, vb2
        n = 3
    if P[o + 1] != 0.0:
        z[n], z[n + 1], z[n + 2] = wx, wy, wz
        n += 3
    if P[o + 2] != 0.0:
        z[n], z[n + 1], z[n + 2] = g0, g1, g2
        n += 3
    if P[o + 3] != 0.0:
        for i in range(4):
            z[n + i] = u[i] / speed
        n += 4
    if P[o + 4] != 0.0:
        for i in range(4):
            s = u[i] / speed
            z[n + i] = s * s
        n += 4
    a = o + 8 + L + 1
    for i in range(n):
        z[i] = (z[i] - P[a + i]) / P[a + n + i]
    a += 2 * n
    for k in range(L):
        d_in, d_out = int(P[o + 8 + k]), int(P[o + 9 + k])
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
    R00, R01, R02, R10, R11, R12, R20, R21, R22 = R_entries(x[6], x[7], x[8], x[9])
    vx, vy, vz = x[3], x[4], x[5]
    wx, wy, wz = x[10], x[11], x[12]
    vb0 = R00 * vx + R10 * vy + R20 * vz  # v_b = R^T v
    vb1 = R01 * vx + R11 * vy + R21 * vz
    vb2 = R02 * vx + R12 * vy + R22 * vz
    # rotor wrench with per-rotor thrust scale and yaw-torque gain
    T = 0.0
    G0 = 0.0
    G1 = 0.0
    G2 = 0.0
    omega_sum = 0.0
    for i in range(4):
        u2 = u_eff[i] * u_eff[i]
        sc = P[P_SCALE + i]
        T += P[P_B + 0 * 4 + i] * sc * u2
        G0 += P[P_B + 1 * 4 + i] * sc * u2
        G1 += P[P_B + 2 * 4 + i] * sc * u2
        G2 += P[P_B + 3 * 4 + i] * P[P_CQGAIN] * u2
        omega_sum += u_eff[i]
    f0 = -P[P_LIN] * vb0 - P[P_QUAD] * abs(vb0) * vb0 + P[P_BBIAS] + f_ext[0] - P[P_RDRAG] * omega_sum * vb0
    f1 = -P[P_LIN + 1] * vb1 - P[P_QUAD + 1] * abs(vb1) * vb1 + P[P_BBIAS + 1] + f_ext[1] \
        - P[P_RDRAG] * omega_sum * vb1
    f2 = T - P[P_LIN + 2] * vb2 - P[P_QUAD + 2] * abs(vb2) * vb2 + P[P_BBIAS + 2] + f_ext[2]
    if P[P_GE] != 0.0:
        h = x[2] + R20 * P[P_MARKER] + R21 * P[P_MARKER + 1] + R22 * P[P_MARKER + 2] - P[P_GZ]
        h = max(h, MIN_GROUND_HEIGHT)
        f2 += P[P_GE] * T / (h * h)
    t0 = t1 = t2 = 0.0
    if P[P_RDM] != 0.0 or P[P_TLIFT] != 0.0:
        # at each hub r_i (from the CG: the layout, the hub height, less a CG offset), airspeed w = v_b + ω × r_i:
        # the rotor drag's H-force -k u_i [w_x, w_y, 0] acts there (its moment about the CG), and the rotor's
        # thrust grows by k_lift (w_x² + w_y²)
        for i in range(4):
            rx = P[P_HUB + 3 * i] - P[P_CG]
            ry = P[P_HUB + 3 * i + 1] - P[P_CG + 1]
            rz = P[P_HUB + 3 * i + 2]
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
    ax = (R00 * f0 + R01 * f1 + R02 * f2 + P[P_WIND]) / m
    ay = (R10 * f0 + R11 * f1 + R12 * f2 + P[P_WIND + 1]) / m
    az = (R20 * f0 + R21 * f1 + R22 * f2 + P[P_WIND + 2]) / m - G
    t0 += G0 - P[P_CG + 1] * T + P[P_TBIAS + 0] + P[P_FLAP] * vb1 + tau_ext[0]
    t1 += G1 + P[P_CG + 0] * T + P[P_TBIAS + 1] - P[P_FLAP] * vb0 + tau_ext[1]
    t2 += G2 + P[P_TBIAS + 2] + tau_ext[2]
    if P[P_REM_ON] != 0.0:
        for k in range(3):
            base = P_REM + 11 * k
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
    Jx, Jy, Jz = P[P_J], P[P_J + 1], P[P_J + 2]
    # tau + (J w) x w
    t0 += Jy * wy * wz - Jz * wz * wy
    t1 += Jz * wz * wx - Jx * wx * wz
    t2 += Jx * wx * wy - Jy * wy * wx
    return ax, ay, az, t0 / Jx, t1 / Jy, t2 / Jz


@nb.njit(cache=True)
def plant_accels(x, u_eff, P, f_ext, tau_ext):
    """World acceleration of the CG and body angular acceleration (TRUE physics)."""
    ax, ay, az, bx, by, bz = _accels(x, u_eff, P, f_ext, tau_ext)
    return np.array([ax, ay, az]), np.array([bx, by, bz])


@nb.njit(cache=True, inline="always")
def rigid_body_deriv(x, u_eff, P, f_ext, tau_ext, dx):
    """Derivatives of p, v, q, ω (``dx[0:13]``) with the rotor speeds ``u_eff`` acting."""
    ax, ay, az, bx, by, bz = _accels(x, u_eff, P, f_ext, tau_ext)
    dx[0] = x[3]
    dx[1] = x[4]
    dx[2] = x[5]
    dx[3] = ax
    dx[4] = ay
    dx[5] = az
    q0, q1, q2, q3 = x[6], x[7], x[8], x[9]
    w0, w1, w2 = x[10], x[11], x[12]
    # q̇ = ½ q ⊗ [0, ω]
    dx[6] = 0.5 * (-q1 * w0 - q2 * w1 - q3 * w2)
    dx[7] = 0.5 * (q0 * w0 + q2 * w2 - q3 * w1)
    dx[8] = 0.5 * (q0 * w1 + q3 * w0 - q1 * w2)
    dx[9] = 0.5 * (q0 * w2 + q1 * w1 - q2 * w0)
    dx[10] = bx
    dx[11] = by
    dx[12] = bz


@nb.njit(cache=True)
def tracked_pv(x, r):
    """Position and velocity (world) of the tracked point at body offset ``r``: ``p + R r``, ``v + R (ω × r)``
    (the inverse of :func:`cg_from_tracked`)."""
    R00, R01, R02, R10, R11, R12, R20, R21, R22 = R_entries(x[6], x[7], x[8], x[9])
    c0 = x[11] * r[2] - x[12] * r[1]
    c1 = x[12] * r[0] - x[10] * r[2]
    c2 = x[10] * r[1] - x[11] * r[0]
    return (x[0] + R00 * r[0] + R01 * r[1] + R02 * r[2], x[1] + R10 * r[0] + R11 * r[1] + R12 * r[2],
            x[2] + R20 * r[0] + R21 * r[1] + R22 * r[2], x[3] + R00 * c0 + R01 * c1 + R02 * c2,
            x[4] + R10 * c0 + R11 * c1 + R12 * c2, x[5] + R20 * c0 + R21 * c1 + R22 * c2)


@nb.njit(cache=True)
def cg_from_tracked(x, r):
    """In place: a state of the tracked point (body offset ``r`` from the CG) → the CG's:
    ``p - R r``, ``v - R (ω × r)``."""
    R00, R01, R02, R10, R11, R12, R20, R21, R22 = R_entries(x[6], x[7], x[8], x[9])
    c0 = x[11] * r[2] - x[12] * r[1]
    c1 = x[12] * r[0] - x[10] * r[2]
    c2 = x[10] * r[1] - x[11] * r[0]
    x[0] -= R00 * r[0] + R01 * r[1] + R02 * r[2]
    x[1] -= R10 * r[0] + R11 * r[1] + R12 * r[2]
    x[2] -= R20 * r[0] + R21 * r[1] + R22 * r[2]
    x[3] -= R00 * c0 + R01 * c1 + R02 * c2
    x[4] -= R10 * c0 + R11 * c1 + R12 * c2
    x[5] -= R20 * c0 + R21 * c1 + R22 * c2


@nb.njit(cache=True)
def rigid_body_rk4(x, u0, um, u1, P, dt, frozen, zero, k, xs, xn):
    """One RK4 step of p, v, q, ω (13 states) into ``xn``, the rotor speeds ``u0``, ``um``, ``u1`` acting at
    the start, middle and end of the step; ``frozen``: ω held.  ``k`` (4, 13) and ``xs`` (13,) are
    scratch: the rollout and the replay take millions of steps, and small arrays cost more than the
    arithmetic.  The quaternion is renormalised."""
    for s in range(4):
        if s > 0:
            c = dt if s == 3 else 0.5 * dt
            for j in range(13):
                xs[j] = x[j] + c * k[s - 1, j]
        else:
            for j in range(13):
                xs[j] = x[j]
        rigid_body_deriv(xs, u0 if s == 0 else (u1 if s == 3 else um), P, zero, zero, k[s])
        if frozen:
            k[s, 10] = k[s, 11] = k[s, 12] = 0.0
    for j in range(13):
        xn[j] = x[j] + dt / 6.0 * (k[0, j] + 2.0 * k[1, j] + 2.0 * k[2, j] + k[3, j])
    n = math.sqrt(xn[6] ** 2 + xn[7] ** 2 + xn[8] ** 2 + xn[9] ** 2)
    for j in range(6, 10):
        xn[j] /= n


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
    p = x[0:3] + matvec(R, r)
    v = x[3:6] + matvec(R, cross(w, r))
    acc = a + matvec(R, cross(alpha, r) + cross(w, cross(w, r)))
    return p, v, acc


def hover_state(vehicle, p0, yaw0=0.0) -> np.ndarray:
    x = np.zeros(N_X)
    x[0:3] = p0
    x[6:10] = [math.cos(yaw0 / 2), 0.0, 0.0, math.sin(yaw0 / 2)]
    x[13:17] = vehicle.hover_speed
    return x
