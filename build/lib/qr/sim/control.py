"""Controllers: LQR on the double integrator (thesis eqs. 5.6-5.12) and a PD attitude loop.

High level: ``a_des = a_ref + K (x_ref - x)`` with ``x = [p, v]`` and ``K`` from the
continuous-time algebraic Riccati equation (scipy).  A disturbance estimate
enters as an acceleration offset (the thesis's "with ANN model" controller):
``a_cmd = a_des - R f_est / m``.

Low level: the thrust vector ``m (a_cmd - g)`` fixes the desired body z axis and
the thrust (projected on the current body z); the reference yaw completes the
desired attitude; a PD law on SO(3) with gyroscopic cancellation gives the
torques; the inverse rotor map gives rotor speeds within the vehicle's limits.
The controller only knows the NOMINAL vehicle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np
from scipy.linalg import solve_continuous_are

from ..frames import G
from ..frames_compiled import cross, quat_to_R

# controller parameter vector layout
C_MASS, C_J, C_BINV, C_KP, C_KD, C_KR, C_KW, C_UMIN, C_UMAX, C_TILT = 0, 1, 4, 20, 23, 26, 29, 32, 33, 34
N_C = 35


def lqr_gain(q_pos=100.0, q_vel=10.0, r=0.2) -> np.ndarray:
    """LQR gain (3 x 6) of the double integrator ``ẋ = A x + B a`` (eqs. 5.7-5.10).

    With the thesis's weights Q = diag(100 I, 10 I), R = 0.2 I this is eq. 5.11:
    22.3607 on position, 9.7325 on velocity.
    """
    A = np.block([[np.zeros((3, 3)), np.eye(3)], [np.zeros((3, 3)), np.zeros((3, 3))]])
    B = np.vstack([np.zeros((3, 3)), np.eye(3)])
    Q = np.diag([q_pos] * 3 + [q_vel] * 3)
    R = r * np.eye(3)
    P = solve_continuous_are(A, B, Q, R)
    return np.linalg.solve(R, B.T @ P)


@dataclass
class Gains:
    q_pos: float = 100.0
    q_vel: float = 10.0
    r: float = 0.2
    attitude_natural_freq: float = 12.0  # rad/s; leaves margin for 30 ms of rotor delay
    attitude_damping: float = 0.9
    max_tilt_deg: float = 40.0


def controller_params(vehicle, gains: Gains | None = None) -> np.ndarray:
    g = gains or Gains()
    K = lqr_gain(g.q_pos, g.q_vel, g.r)
    C = np.zeros(N_C)
    C[C_MASS] = vehicle.mass
    C[C_J:C_J + 3] = vehicle.inertia
    C[C_BINV:C_BINV + 16] = np.linalg.inv(vehicle.rotors.matrix).ravel()
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
def control(x, p_ref, v_ref, a_ref, yaw, yaw_rate, a_comp, C):
    """Rotor-speed command (4,) and desired attitude (3, 3) for state ``x``."""
    p = x[0:3]
    v = x[3:6]
    R = quat_to_R(x[6:10])
    w = x[10:13]
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
    E = Rd.T @ R - R.T @ Rd
    e_R = 0.5 * np.array([E[2, 1], E[0, 2], E[1, 0]])
    w_d = R.T @ (Rd @ np.array([0.0, 0.0, yaw_rate]))
    e_w = w - w_d
    J = C[C_J:C_J + 3]
    alpha = -C[C_KR:C_KR + 3] * e_R - C[C_KW:C_KW + 3] * e_w
    Jw = J * w
    tau = J * alpha - cross(Jw, w)
    wrench = np.array([T, tau[0], tau[1], tau[2]])
    Binv = C[C_BINV:C_BINV + 16].reshape((4, 4))
    u2 = Binv @ wrench
    u = np.empty(4)
    lo = C[C_UMIN] * C[C_UMIN]
    hi = C[C_UMAX] * C[C_UMAX]
    for i in range(4):
        u[i] = math.sqrt(min(max(u2[i], lo), hi))
    return u, Rd
