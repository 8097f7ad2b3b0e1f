"""Stability of a plant whose force model takes the body acceleration as input (thesis §5.3.1):
the eigenvalues of M_{v,a} (eq. 5.15) of the lagged evaluation (eq. 5.13), and the physical reading (mass
matrix ``m I - W_a``); why both readings are reported: docs/simulate.md "Stability", "What we corrected in the thesis".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

UNSTABLE_TOL = 1e-9  # |λ| above 1 + this counts as unstable (numerical round-off only)


def m_va(W_v: np.ndarray, W_a: np.ndarray, mass: float, dt: float) -> np.ndarray:
    """Eq. 5.15: the (6, 6) velocity/acceleration propagation matrix at hover."""
    W_v = np.asarray(W_v, dtype=float).reshape(3, 3)
    W_a = np.asarray(W_a, dtype=float).reshape(3, 3)
    return np.block([[np.eye(3), dt * np.eye(3)], [W_v / mass, W_a / mass]])


def eigenvalues(W_v, W_a, mass: float, dt: float) -> np.ndarray:
    """Eigenvalues of ``M_{v,a}``, largest modulus first (ties: real part, then imaginary part)."""
    lam = np.linalg.eigvals(m_va(W_v, W_a, mass, dt))
    order = np.lexsort((lam.imag, -lam.real, -np.round(np.abs(lam), 12)))
    return lam[order]


@dataclass(frozen=True)
class Analysis:
    """One a_b-input model's eigen-analysis at hover (eq. 5.15) and its implicit (physical) reading."""

    eigenvalues: np.ndarray  # of M_{v,a}
    max_abs_eig: float
    n_above_one: int
    lagged_prediction: str  # diverges | bounded
    a_block_eigs: np.ndarray  # of W_a / m
    effective_mass_min_real: float  # of m I - W_a
    implicit_prediction: str  # stable | unstable | ill-posed


def analyse(W_v, W_a, mass: float, dt: float) -> Analysis:
    """Eigenvalues, the |λ| > 1 flags, and the implicit (physical) reading."""
    lam = eigenvalues(W_v, W_a, mass, dt)
    n_above = int(np.sum(np.abs(lam) > 1.0 + UNSTABLE_TOL))
    a_eigs = np.linalg.eigvals(np.asarray(W_a, dtype=float) / mass)
    m_eff = np.linalg.eigvals(mass * np.eye(3) - np.asarray(W_a, dtype=float))
    if np.min(np.abs(m_eff)) < 1e-6 * mass:
        implicit = "ill-posed"
    elif np.any(m_eff.real <= 0):
        implicit = "unstable"
    else:
        implicit = "stable"
    return Analysis(lam, float(np.abs(lam).max()), n_above, "diverges" if n_above else "bounded", a_eigs,
                    float(m_eff.real.min()), implicit)


def format_eigs(lam) -> str:
    return "; ".join(f"{z.real:.4f}{z.imag:+.4f}i" for z in np.asarray(lam, dtype=complex))


def growth_per_step(x: np.ndarray, window: int = 20) -> float:
    """Mean per-sample growth factor of ``|Δx|`` over the last ``window`` samples (1 when flat)."""
    d = np.linalg.norm(np.diff(np.asarray(x, dtype=float), axis=0), axis=1)
    d = d[-window:]
    d = d[d > 0]
    if len(d) < 3:
        return 1.0
    slope = np.polyfit(np.arange(len(d)), np.log(d), 1)[0]
    return float(np.exp(slope))
