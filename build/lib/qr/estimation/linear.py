"""The reference path of the linear filters (position, rotors): ``filterpy.kalman.KalmanFilter``.

One predict per sample with that sample's own ``dt``; the update is skipped on
a dropout (the state is predicted through).  Slow (a Python loop over
samples) and kept as the yardstick the compiled path must match to 1e-9.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from tqdm import tqdm

from .nis import Innovations
from .smoother import rts_linear


def kalman_reference(t: np.ndarray, z: np.ndarray, F_of: Callable, Q_of: Callable, H: np.ndarray, R: np.ndarray,
                     x0: np.ndarray, P0: np.ndarray, smooth: bool = False, progress: bool = False,
                     label: str = "filter"):
    """Filter (and optionally RTS-smooth) ``z`` (N, dz); rows with any NaN are dropouts.

    Returns means (N, n), variances (N, n) and :class:`Innovations` (one column).
    """
    from filterpy.kalman import KalmanFilter  # imported here: the fast path never needs it

    N, dz = z.shape
    n = len(x0)
    kf = KalmanFilter(dim_x=n, dim_z=dz)
    kf.x = np.asarray(x0, dtype=float).reshape(n, 1).copy()
    kf.P = np.asarray(P0, dtype=float).copy()
    kf.H = H
    kf.R = R
    valid = np.all(np.isfinite(z), axis=1)
    X = np.empty((N, n))
    Ps = np.empty((N, n, n))
    nis = np.full((N, 1), np.nan)
    logdet = np.full((N, 1), np.nan)
    for k in tqdm(range(N), desc=f"{label} (reference)", disable=not progress, mininterval=1.0):
        if k:
            dt = t[k] - t[k - 1]
            kf.predict(F=F_of(dt), Q=Q_of(dt))
        if valid[k]:
            kf.update(z[k].reshape(dz, 1))
            nis[k, 0] = (kf.y.T @ kf.SI @ kf.y).item()
            logdet[k, 0] = np.linalg.slogdet(kf.S)[1]
        X[k] = kf.x[:, 0]
        Ps[k] = kf.P
    if smooth:
        dts = np.diff(t)
        X, Ps = rts_linear(X, Ps, [F_of(d) for d in dts], [Q_of(d) for d in dts])
    var = np.einsum("nii->ni", Ps).copy()
    return X, var, Innovations(nis, logdet, dz)
