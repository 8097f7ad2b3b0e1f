"""Controllers: LQR on the double integrator (thesis eqs. 5.6-5.12) and a PD attitude loop on SO(3) with
gyroscopic cancellation; a disturbance estimate enters as ``a_cmd = a_des - R f_est / m``.  The controller
only knows the NOMINAL vehicle.  docs/simulate.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from ..frames import G
from ..frames_compiled import cross, matvec, quat_to_R
from ..plant_state import X_POS, X_QUAT, X_RATE, X_VEL

# controller parameter vector layout
C_MASS, C_J, C_BINV, C_KP, C_KD, C_KR, C_KW, C_UMIN, C_UMAX, C_TILT = 0, 1, 4, 20, 23, 26, 29, 32, 33, 34
N_C = 35


def lqr_gain(q_pos=100.0, q_vel=10.0, r=0.2) -> np.ndarray:
    """LQR gain (3 x 6) of the double integrator ``ẋ = A x + B a`` (eqs. 5.7-5.10).

    With the thesis's weights Q = diag(100 I, 10 I), R = 0.2 I this is eq. 5.11:
    22.3607 on position, 9.7325 on velocity.  The Riccati equation of a double integrator per axis
    has the closed form ``k_p = √(q_p/r)``, ``k_v = √(q_v/r + 2 k_p)`` (tested against scipy's
    solver): square roots round the same everywhere, a LAPACK solve does not.
    """
    kp = math.sqrt(q_pos / r)
    kv = math.sqrt(q_vel / r + 2 * kp)
    return np.hstack([kp * np.eye(3), kv * np.eye(3)])


@dataclass
class Gains:
    q_pos: float = 100.0
    q_vel: float = 10.0
    r: float = 0.2
    attitude_natural_freq: float = 12.0  # rad/s; flies a rotor lag (delay + motor time constant) up to LAG_AT_DEFAULT
    attitude_damping: float = 0.9
    max_tilt_deg: float = 40.0


# The longest rotor lag (pure delay + first-order motor time constant, s) the default attitude loop flies
# with margin: the synthetic flights with 40 ms of delay on a 20 ms motor (the Crazyflie) still track within
# 3 cm; at 47 ms the loop oscillated and crashed.  A vehicle's attitude gains are tuned on the vehicle,
# its lag included, so a slower vehicle gets a proportionally slower loop (``for_lag``).
LAG_AT_DEFAULT = 0.06


def for_lag(gains: Gains, lag: float) -> Gains:
    """``gains`` with the attitude loop slowed so that ``natural_freq x lag`` stays at the default's
    ``12 rad/s x LAG_AT_DEFAULT``: the phase a lag costs at crossover is ``crossover x lag``."""
    from dataclasses import replace

    if lag <= LAG_AT_DEFAULT:
        return gains
    return replace(gains, attitude_natural_freq=gains.attitude_natural_freq * LAG_AT_DEFAULT / lag)


def controller_params(vehicle, gains: Gains | None = None) -> np.ndarray:
    g = gains or Gains()
    K = lqr_gain(g.q_pos, g.q_vel, g.r)
    C = np.zeros(N_C)
    C[C_MASS] = vehicle.mass
    C[C_J:C_J + 3] = vehicle.inertia
    C[C_BINV:C_BINV + 16] = vehicle.rotors.inverse.ravel()
    C[C_KP:C_KP + 3] = np.diag(K[:, :3])
    C[C_KD:C_KD + 3] = np.diag(K[:, 3:])
    wn, z = g.attitude_natural_freq, g.attitude_damping
    C[C_KR:C_KR + 3] = wn * wn
    C[C_KW:C_KW + 3] = 2 * z * wn
    C[C_UMIN] = vehicle.rotor_speed_min
    C[C_UMAX] = vehicle.rotor_speed_max
    C[C_TILT] = math.radians(g.max_tilt_deg)
    return C


@nb.njit(cache=True)
def matmul(A, B):
    """``A @ B`` in index order (see ``matvec``)."""
    out = np.zeros((A.shape[0], B.shape[1]))
    for j in range(B.shape[1]):
        out[:, j] = matvec(A, B[:, j].copy())
    return out


@nb.njit(cache=True)
def control(x, p_ref, v_ref, a_ref, yaw, yaw_rate, a_comp, C):
    """Rotor-speed command (4,) and desired attitude (3, 3) for state ``x``."""
    p = x[X_POS]
    v = x[X_VEL]
    R = quat_to_R(x[X_QUAT])
    w = x[X_RATE]
    a = a_ref + C[C_KP:C_KP + 3] * (p_ref - p) + C[C_KD:C_KD + 3] * (v_ref - v) + a_comp
    # thrust direction with a floor on vertical thrust and a tilt limit
    F = a.copy()
    F[2] += G
    F[2] = max(F[2], 0.3 * G)
    h = math.sqrt(F[0] ** 2 + F[1] ** 2)
    hmax = F[2] * math.tan(C[C_TILT])
    if h > hmax:
        F[0] *= hmax / h
        F[1] *= hmax / h
    m = C[C_MASS]
    b3 = F / math.sqrt(F[0] ** 2 + F[1] ** 2 + F[2] ** 2)
    T = m * (F[0] * R[0, 2] + F[1] * R[1, 2] + F[2] * R[2, 2])
    T = max(T, 0.0)
    b1c = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    b2 = cross(b3, b1c)
    b2 /= math.sqrt(b2[0] ** 2 + b2[1] ** 2 + b2[2] ** 2)
    b1 = cross(b2, b3)
    Rd = np.empty((3, 3))
    Rd[:, 0] = b1
    Rd[:, 1] = b2
    Rd[:, 2] = b3
    E = matmul(Rd.T, R) - matmul(R.T, Rd)
    e_R = 0.5 * np.array([E[2, 1], E[0, 2], E[1, 0]])
    w_d = matvec(R.T, matvec(Rd, np.array([0.0, 0.0, yaw_rate])))
    e_w = w - w_d
    J = C[C_J:C_J + 3]
    alpha = -C[C_KR:C_KR + 3] * e_R - C[C_KW:C_KW + 3] * e_w
    Jw = J * w
    tau = J * alpha - cross(Jw, w)
    wrench = np.array([T, tau[0], tau[1], tau[2]])
    Binv = C[C_BINV:C_BINV + 16].reshape((4, 4))
    u2 = matvec(Binv, wrench)
    lo = C[C_UMIN] * C[C_UMIN]
    hi = C[C_UMAX] * C[C_UMAX]
    if not _within(u2, lo, hi):
        u2 = desaturate(Binv, wrench, lo, hi)
    u = np.empty(4)
    for i in range(4):
        u[i] = math.sqrt(min(max(u2[i], lo), hi))
    return u, Rd


@nb.njit(cache=True)
def _within(u2, lo, hi):
    for i in range(u2.shape[0]):
        if u2[i] < lo or u2[i] > hi:
            return False
    return True


@nb.njit(cache=True)
def _largest_share(base, part, lo, hi):
    """The largest ``s`` in [0, 1] with ``base + s part`` within [lo, hi] on every rotor that ``base`` holds
    within it (a rotor ``base`` already takes out of range is left to the clip)."""
    s = 1.0
    for i in range(base.shape[0]):
        if base[i] < lo or base[i] > hi:
            continue
        if part[i] > 0.0 and base[i] + part[i] > hi:
            s = min(s, (hi - base[i]) / part[i])
        elif part[i] < 0.0 and base[i] + part[i] < lo:
            s = min(s, (lo - base[i]) / part[i])
    return max(s, 0.0)


@nb.njit(cache=True)
def desaturate(Binv, wrench, lo, hi):
    """Squared rotor speeds for ``wrench`` when some rotor would leave [lo, hi]: the yaw torque is given up
    first, then roll and pitch together, the thrust kept (as flight stacks mix): clipping each rotor alone
    turns a yaw demand beyond a weak yaw authority (the Hummingbird's C_Q / (C_T l) ~ 0.1) into roll and
    pitch torques, and the attitude loop into a limit cycle between the rotor limits."""
    thrust = matvec(Binv, np.array([wrench[0], 0.0, 0.0, 0.0]))
    rp = matvec(Binv, np.array([0.0, wrench[1], wrench[2], 0.0]))
    yaw = matvec(Binv, np.array([0.0, 0.0, 0.0, wrench[3]]))
    s_rp = _largest_share(thrust, rp, lo, hi)
    base = thrust + s_rp * rp
    return base + _largest_share(base, yaw, lo, hi) * yaw
