"""Integrator chains: the kinematic model shared by all three filters.

Order ``m`` states ``[x, x', ..., x^(m-1)]``, white noise on ``x^(m)``: position and attitude ``m = 4`` (thesis
eqs. 4.4, 4.15), each rotor ``m = 3`` (eq. 4.28).  Process noise ``thesis`` (as printed, once per sample) or
``exact`` (``q`` a spectral density integrated over each sample's own ``dt``): docs/filter.md.
"""

from __future__ import annotations

import math

import numpy as np

DISCRETISATIONS = ("thesis", "exact")


def transition(m: int, dt: float) -> np.ndarray:
    """Φ(dt) = exp(N dt), ``N`` the shift matrix: ``Φ[i, j] = dt^(j-i) / (j-i)!`` (eqs. 4.8, 4.32)."""
    P = np.eye(m)
    for i in range(m):
        for j in range(i + 1, m):
            P[i, j] = dt ** (j - i) / math.factorial(j - i)
    return P


def process_noise(m: int, dt: float, q: float, discretisation: str) -> np.ndarray:
    """Q(dt) for white noise of intensity ``q`` on the ``m``-th derivative."""
    Q = np.zeros((m, m))
    if discretisation == "thesis":
        Q[m - 1, m - 1] = q
        return Q
    for i in range(m):
        for j in range(m):
            a, b = m - 1 - i, m - 1 - j
            Q[i, j] = q * dt ** (a + b + 1) / (math.factorial(a) * math.factorial(b) * (a + b + 1))
    return Q

