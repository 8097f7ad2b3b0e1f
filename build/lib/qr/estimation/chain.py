"""Integrator chains: the kinematic model shared by all three filters.

A chain of order ``m`` has the states ``[x, x', ..., x^(m-1)]`` and white
noise on ``x^(m)``: position ``m = 4`` (p, v, a, j; thesis eq. 4.4), the
vector part of the attitude filter ``m = 4`` (θ, ω, α, α̇; eq. 4.15) and each
rotor ``m = 3`` (u, u̇, ü; eq. 4.28).

Two discretisations of the process noise:

- ``thesis``: the matrices as printed, ``q`` added to the last state once per
  sample (eqs. 4.6a, 4.31a; eq. 4.20's ``dt²`` scaling lives in the ESKF);
- ``exact``: ``q`` is the power spectral density of the white noise and
  ``Q(dt) = q ∫₀^dt Φ(s) e eᵀ Φ(s)ᵀ ds``, so every sample's own ``dt`` gets the
  noise that accumulates over it (irregular stamps, predictions through dropouts).
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

