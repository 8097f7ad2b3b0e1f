"""Stability of a plant whose force model takes the body acceleration as input (thesis §5.3.1).

A linear model ``f_a = W_v v_b + W_a a_b + ... + b`` evaluated with the
acceleration of the previous step (the thesis's simulation, eq. 5.13) makes
velocity and acceleration a discrete-time system; at hover (``R = I``) its
matrix is eq. 5.15::

    M_{v,a} = [[I, dt I], [W_v / m, W_a / m]]

and the run diverges when an eigenvalue has ``|λ| > 1``.  Because
``det(λ I - M) = det((λ - 1)(λ I - W_a/m) - dt W_v/m)``, a model whose ``W_v``
and ``W_a`` act axis by axis has, per axis, the two roots of
``λ² - (1 + a) λ + (a - dt v) = 0`` (``a = W_a,ii / m``, ``v = W_v,ii / m``):
with small ``dt`` one near 1 and one near ``a``.

Reading eq. 5.16: for small ``dt`` three eigenvalues are always ≈ 1 (velocity
integrating acceleration); the other three are ≈ ``eig(W_a / m)``.  The thesis's
values say ``W_a / m`` has 1.58 ± 0.14i and ≈ 1.00.

What the thesis did not say: |λ| > 1 is a property of that explicit, one-step-lagged
evaluation.  The physical reading solves ``m a_b = F + W_a a_b`` for a consistent
acceleration, i.e. the vehicle behaves as if its mass matrix were ``m I - W_a``;
it is unstable under the position controller only when that matrix is not
positive (an eigenvalue of ``W_a / m`` with real part >= 1) and ill-posed when it
is singular.  A model fitted to labels computed from ``a_b`` itself (eq. 4.34)
is pulled towards ``W_a = m I``, the label's own definition, the more so the
noisier ``a_b`` is (eig(W_a/m) 0.15-0.33 at 0.1 m/s² of noise, 0.93-0.97 at 1 m/s²);
there ``m I - W_a`` vanishes and the model carries no force information at all:
the leak, not the integration scheme, is the root problem.  The study reports both readings and
runs both closed loops.
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
