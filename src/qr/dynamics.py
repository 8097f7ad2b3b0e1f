"""Nominal rigid-body model and the residual labels (thesis eqs. 4.1, 4.34, 4.39, 5.2).

    m a_b = m R^T g + [0, 0, T] + f_a          (4.1b)
    J α   = (J ω) × ω + Γ + τ_a                 (4.1d)

so that ``f_a = m a_b - (m R^T g + [0, 0, T])`` (4.34) and
``τ_a = J α - ((J ω) × ω + Γ)`` (4.39), all in the body frame.  Everything is
vectorised over samples (leading axis N).
"""

from __future__ import annotations

import numpy as np

from .frames import GRAVITY, quat_multiply, quat_to_rot, to_body, to_world


def thrust_torque(u: np.ndarray, vehicle) -> tuple[np.ndarray, np.ndarray]:
    """Nominal thrust T (N,) and torques Γ (N, 3) from rotor speeds (eq. 4.3 / layout)."""
    return vehicle.rotors.thrust_torque(u)


def nominal_force(R: np.ndarray, T: np.ndarray, mass: float) -> np.ndarray:
    """Body-frame force the nominal model predicts: ``m R^T g + [0, 0, T]``."""
    g_b = to_body(R, np.broadcast_to(GRAVITY, (len(R), 3)))
    f = mass * g_b
    f[:, 2] += T
    return f


def nominal_torque(omega: np.ndarray, Gamma: np.ndarray, J: np.ndarray) -> np.ndarray:
    """``(J ω) × ω + Γ`` for a diagonal inertia ``J`` (3,)."""
    return np.cross(omega * J, omega) + Gamma


def residual_force(a_b: np.ndarray, R: np.ndarray, u: np.ndarray, vehicle) -> np.ndarray:
    """``f_a`` (eq. 4.34), N, body frame."""
    T, _ = thrust_torque(u, vehicle)
    return vehicle.mass * a_b - nominal_force(R, T, vehicle.mass)


def residuals(s, vehicle) -> np.ndarray:
    """``[f_a, τ_a]`` (N, 6) from a :class:`qr.effects.Signals`.

    Thrust and torques come from the signals' force-row and torque-row rotor
    speeds (the same as ``u²`` unless matched ones are given; see qr.estimation.matched).
    """
    from .effects import wrench

    T, Gamma = wrench(s, vehicle)
    f = vehicle.mass * s.a_b - nominal_force(s.R, T, vehicle.mass)
    tau = s.alpha * vehicle.inertia - nominal_torque(s.omega, Gamma, vehicle.inertia)
    return np.hstack([f, tau])


def derivatives(p, v_w, q, omega, u, vehicle, f_a=None, tau_a=None):
    """Rigid-body state derivatives (eq. 5.2) with optional body-frame f_a, τ_a.

    Returns ``(p_dot, v_dot, q_dot, omega_dot)``; ``v`` is the world velocity,
    ``q`` scalar first (``q_dot = ½ q ⊗ [0, ω]``).
    """

    R = quat_to_rot(q)
    T, Gamma = thrust_torque(u, vehicle)
    f_b = np.zeros_like(omega)
    f_b[:, 2] = T
    if f_a is not None:
        f_b = f_b + f_a
    v_dot = GRAVITY + to_world(R, f_b) / vehicle.mass
    tau = nominal_torque(omega, Gamma, vehicle.inertia)
    if tau_a is not None:
        tau = tau + tau_a
    omega_dot = tau / vehicle.inertia
    q_dot = 0.5 * quat_multiply(q, np.hstack([np.zeros((len(q), 1)), omega]))
    return v_w, v_dot, q_dot, omega_dot
