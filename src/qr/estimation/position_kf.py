"""Position: linear Kalman filter on ``[p, v, a, j]`` (thesis §4.2.1.1, eqs. 4.4–4.10).

The three axes share Φ (eq. 4.8), Q (4.6a), H (4.10) and R (4.6b): the
12-state matrices are Kronecker products of the 4-state chain with ``I₃``,
state order ``[px py pz vx vy vz ax ay az jx jy jz]``.
"""

from __future__ import annotations

import numpy as np

from . import chain
from .linear import kalman_reference
from .smoother import equilibration

THESIS_Q = 100 * 0.1  # eq. 4.6a: Q = 100 [[0, 0], [0, 0.1 I₃]] on the jerk block, per sample
THESIS_R = 0.0002**2  # eq. 4.6b
H = np.hstack([np.eye(3), np.zeros((3, 9))])  # eq. 4.10
P0_DERIVS = (1.0, 1e2, 1e4)  # initial variances of v, a, j: (1 m/s)², (10 m/s²)², (100 m/s³)²


def transition(dt: float) -> np.ndarray:
    """Φ of eq. 4.8."""
    return np.kron(chain.transition(4, dt), np.eye(3))


def process_noise(dt: float, q: float, discretisation: str = "thesis") -> np.ndarray:
    """Q of eq. 4.6a (``thesis``) or the integrated white snap of intensity ``q`` (``exact``)."""
    return np.kron(chain.process_noise(4, dt, q, discretisation), np.eye(3))


def measurement_noise(r: float) -> np.ndarray:
    return r * np.eye(3)


def initial(p0, r):
    x0 = np.concatenate([np.asarray(p0, dtype=float), np.zeros(9)])
    return x0, np.diag(np.concatenate([np.full(3, float(r)), np.repeat(P0_DERIVS, 3)]))


def filter_reference(t, p_meas, q, r, discretisation="thesis", smooth=False, progress=False):
    """filterpy position filter; ``p_meas`` (N, 3), NaN rows are dropouts.  Means (N, 12), variances, innovations."""
    valid = np.all(np.isfinite(p_meas), axis=1)
    x0, P0 = initial(p_meas[int(np.argmax(valid))], r)
    return kalman_reference(t, p_meas, transition, lambda dt: process_noise(dt, q, discretisation), H,
                            measurement_noise(r), x0, P0, smooth, progress, "position")


def filter_fast(t, p_meas, q, r, discretisation="thesis", smooth=False):
    """Compiled equivalent of :func:`filter_reference`: the three axes share one 4×4 covariance."""
    from . import fast
    from ..linalg_compiled import kernel_array
    from .nis import Innovations

    valid = np.all(np.isfinite(p_meas), axis=1)
    x0, P0 = initial(p_meas[int(np.argmax(valid))], r)
    exact = discretisation == "exact"
    X, V, Ps, nis, logS = fast.chain_forward(t, kernel_array(p_meas), valid, float(q), float(r), exact,
                                             x0.reshape(4, 3).T.copy(), P0[::3, ::3].copy(), smooth)
    if smooth:
        fast.chain_smooth(t, X, Ps, float(q), exact, equilibration(Ps))
        V = np.einsum("nii->ni", Ps)
    X = X.transpose(0, 2, 1).reshape(len(t), 12)
    return X, np.repeat(V, 3, axis=1), Innovations(nis.sum(axis=1, keepdims=True), (3 * logS)[:, None], 3)
