"""The noise floor: how much of the residual is estimation noise, per sample and axis.

The filter's posterior standard deviations (``sd_`` columns) propagated to first order through the residual
labels, calibrated per axis on the difference of the cross-fitting filters' labels (:func:`calibrate`;
without ``sd_`` columns, a robust first-difference estimate).  docs/diagnose.md "How it decides".
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..frames import GRAVITY, skew
from ..states import ACCELERATION, ANGULAR_ACCELERATION, ROTORS

ATTITUDE_SD = ["sd_thx", "sd_thy", "sd_thz"]


def noise_sd(states: pd.DataFrame, R: np.ndarray, vehicle, residual: np.ndarray) -> np.ndarray:
    """Per-sample noise standard deviation of ``[f_a, τ_a]`` (N, 6), before calibration."""
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
    if all(c in states for c in ATTITUDE_SD):
        g_b = np.einsum("nji,j->ni", R, GRAVITY)
        var[:, 0:3] += vehicle.mass**2 * np.einsum("nij,nj->ni", skew(g_b) ** 2, states[ATTITUDE_SD].to_numpy() ** 2)
    var[:, 2] += var_w[:, 0]
    var[:, 3:6] = (vehicle.inertia * sd_al) ** 2 + var_w[:, 1:]
    return np.sqrt(var)


def calibrate(fitprep) -> list[float]:
    """The per-axis factor that scales the noise floor's standard deviations to the label noise the data
    show (1 where fewer than 100 training stamps have both halves' labels).

    ``fitprep`` stacks the cross-fitting halves (labels of the even-sample filter, then of the
    odd-sample one, at the same stamps).
    """
    n = len(fitprep.t) // 2
    ya, yb, sa, sb = fitprep.y[:n], fitprep.y[n:], fitprep.sd[:n], fitprep.sd[n:]
    ok = fitprep.train[:n] & np.isfinite(ya).all(axis=1) & np.isfinite(yb).all(axis=1) \
        & np.isfinite(sa).all(axis=1) & np.isfinite(sb).all(axis=1)
    if ok.sum() < 100:
        return [1.0] * 6
    emp = np.mean((ya[ok] - yb[ok]) ** 2, axis=0)
    model = np.mean(sa[ok] ** 2 + sb[ok] ** 2, axis=0)
    return np.sqrt(np.where(model > 0, emp / np.maximum(model, 1e-300), 1.0)).tolist()


def difference_noise(residual: np.ndarray) -> np.ndarray:
    """White-noise level per axis from first differences (robust: MAD)."""
    d = np.diff(residual, axis=0)
    d = d[np.isfinite(d).all(axis=1)]
    return 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0) / np.sqrt(2)
