"""The noise floor: how much of the residual is estimation noise, per sample and axis.

From the filter's posterior standard deviations (``sd_`` columns of the state
table), propagated to first order through the residual labels:

    f_a = m a_b - m R^T g - T e3     var(f_a,i) = m² Σ_j R_ji² sd(a_j)² + δ_i3 Σ_k (∂T/∂u_k sd(u_k))²
    τ_a = J α - (Jω)×ω - Γ          var(τ_a,i) = J_i² sd(α_i)² + Σ_k (∂Γ_i/∂u_k sd(u_k))²

Without ``sd_`` columns, a robust first-difference estimate of white noise is used.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..states import ACCELERATION, ANGULAR_ACCELERATION, ROTORS


def noise_sd(states: pd.DataFrame, R: np.ndarray, vehicle, residual: np.ndarray) -> np.ndarray:
    """Per-sample noise standard deviation of ``[f_a, τ_a]`` (N, 6)."""
    sd_cols = [f"sd_{c}" for c in ACCELERATION + ANGULAR_ACCELERATION + ROTORS]
    if not all(c in states for c in sd_cols):
        return np.broadcast_to(difference_noise(residual), residual.shape).copy()
    sd_a = states[[f"sd_{c}" for c in ACCELERATION]].to_numpy()
    sd_al = states[[f"sd_{c}" for c in ANGULAR_ACCELERATION]].to_numpy()
    sd_u = states[[f"sd_{c}" for c in ROTORS]].to_numpy()
    u = states[ROTORS].to_numpy()
    B = vehicle.rotors.matrix  # d wrench / d u_k = 2 u_k B[:, k]
    dW = 2.0 * (u * sd_u)[:, None, :] * B[None, :, :]  # (N, 4 wrench rows, 4 rotors)
    var_w = (dW**2).sum(axis=2)
    var = np.empty((len(states), 6))
    var[:, 0:3] = vehicle.mass**2 * np.einsum("nji,nj->ni", R**2, sd_a**2)
    var[:, 2] += var_w[:, 0]
    var[:, 3:6] = (vehicle.inertia * sd_al) ** 2 + var_w[:, 1:]
    return np.sqrt(var)


def difference_noise(residual: np.ndarray) -> np.ndarray:
    """White-noise level per axis from first differences (robust: MAD)."""
    d = np.diff(residual, axis=0)
    d = d[np.isfinite(d).all(axis=1)]
    return 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0) / np.sqrt(2)
