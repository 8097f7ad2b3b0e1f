"""Rotor speeds: one linear Kalman filter per rotor on ``[u, u̇, ü]`` (thesis §4.2.1.3, eqs. 4.28–4.33).

Same matrices for every rotor: Φ (4.32), Q (4.31a), H (4.33), R (4.31b).
"""

from __future__ import annotations

import numpy as np

from . import chain
from .linear import kalman_reference
from .nis import Innovations
from .smoother import equilibration

THESIS_Q = 10000 * 0.1  # eq. 4.31a: Q = 10000 diag(0, 0, 0.1), per sample
THESIS_R = 1.0  # eq. 4.31b
H = np.array([[1.0, 0.0, 0.0]])  # eq. 4.33
RISE_S = 0.05  # initial uncertainty of u̇, ü: the full speed scale within 50 ms


def transition(dt: float) -> np.ndarray:
    """Φ of eq. 4.32."""
    return chain.transition(3, dt)


def process_noise(dt: float, q: float, discretisation: str = "thesis") -> np.ndarray:
    """Q of eq. 4.31a (``thesis``) or the integrated white u⃛ of intensity ``q`` (``exact``)."""
    return chain.process_noise(3, dt, q, discretisation)


def measurement_noise(r: float) -> np.ndarray:
    return np.array([[float(r)]])


def initial(u0, r, speed_scale):
    s = float(speed_scale)
    return np.array([float(u0), 0.0, 0.0]), np.diag([float(r), (s / RISE_S) ** 2, (s / RISE_S**2) ** 2])


def filter_reference(t, u_meas, q, r, discretisation="thesis", smooth=False, speed_scale=None, progress=False):
    """filterpy, one filter per column of ``u_meas`` (N, c).  Means (N, c, 3), variances (N, c, 3), innovations."""
    N, c = u_meas.shape
    X, V = np.empty((N, c, 3)), np.empty((N, c, 3))
    nis, logdet = np.full((N, c), np.nan), np.full((N, c), np.nan)
    for i in range(c):
        z = u_meas[:, i:i + 1]
        u0 = z[np.isfinite(z[:, 0]), 0][0]
        x0, P0 = initial(u0, r, speed_scale or max(abs(u0), 1.0))
        X[:, i], V[:, i], inn = kalman_reference(t, z, transition, lambda dt: process_noise(dt, q, discretisation),
                                                 H, measurement_noise(r), x0, P0, smooth, progress,
                                                 f"rotor {i + 1}")
        nis[:, i], logdet[:, i] = inn.nis[:, 0], inn.logdet[:, 0]
    return X, V, Innovations(nis, logdet, 1)


def filter_fast(t, u_meas, q, r, discretisation="thesis", smooth=False, speed_scale=None):
    """Compiled equivalent of :func:`filter_reference`: rotors with the same dropouts share one covariance."""
    from . import fast
    from ..linalg_compiled import kernel_array

    N, c = u_meas.shape
    X, V = np.empty((N, c, 3)), np.empty((N, c, 3))
    nis, logdet = np.full((N, c), np.nan), np.full((N, c), np.nan)
    exact = discretisation == "exact"
    valid = np.isfinite(u_meas)
    groups: dict[bytes, list[int]] = {}
    for i in range(c):
        groups.setdefault(valid[:, i].tobytes(), []).append(i)
    for cols in groups.values():
        ok = valid[:, cols[0]]
        u0 = u_meas[int(np.argmax(ok)), cols]
        P0s = [initial(u, r, speed_scale or max(abs(u), 1.0))[1] for u in u0]
        if any(not np.array_equal(P, P0s[0]) for P in P0s):  # no common covariance: one rotor at a time
            for i in cols:
                Xi, Vi, inn = filter_fast(t, u_meas[:, [i]], q, r, discretisation, smooth,
                                          max(abs(u_meas[int(np.argmax(ok)), i]), 1.0))
                X[:, i], V[:, i], nis[:, i], logdet[:, i] = Xi[:, 0], Vi[:, 0], inn.nis[:, 0], inn.logdet[:, 0]
            continue
        x0 = np.column_stack([u0, np.zeros((len(cols), 2))])
        Xg, Vg, Ps, nisg, logS = fast.chain_forward(t, kernel_array(u_meas[:, cols]), ok, float(q), float(r), exact, x0,
                                                    P0s[0], smooth)
        if smooth:
            fast.chain_smooth(t, Xg, Ps, float(q), exact, equilibration(Ps))
            Vg = np.einsum("nii->ni", Ps)
        X[:, cols] = Xg
        V[:, cols] = Vg[:, None, :]
        nis[:, cols] = nisg
        logdet[:, cols] = logS[:, None]
    return X, V, Innovations(nis, logdet, 1)
