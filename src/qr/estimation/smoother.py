"""Rauch–Tung–Striebel smoothing: the same models run backward over the filtered flight (zero-lag
derivatives; docs/filter.md): ``filterpy.kalman.rts_smoother`` for the linear filters, the same recursion on
the ESKF's error state (:func:`qr.estimation.attitude_eskf.rts_eskf`).

Both on equilibrated states ``D x`` (:func:`equilibration`, unit typical variance): a chain's variances span
~14 orders of magnitude, and the backward pass's inverses drop from cond ≈ 1e7–1e12 to ≈ 1e2–1e3.
"""

from __future__ import annotations

import numpy as np


def equilibration(Ps: np.ndarray) -> np.ndarray:
    """Diagonal of ``D``: one over each state's median filtered standard deviation."""
    return 1.0 / np.sqrt(np.median(np.einsum("nii->ni", Ps), axis=0))


def rts_linear(X, Ps, Fs, Qs):
    """Smoothed means and covariances of a linear filter's posteriors (N, n), (N, n, n).

    ``Fs[k]``, ``Qs[k]`` take sample ``k`` to ``k + 1`` (``len = N - 1``).
    """
    from filterpy.kalman import rts_smoother

    n = X.shape[1]
    d = equilibration(Ps)
    Dm, Di = d[:, None], 1.0 / d[None, :]
    Fs = [Dm * F * Di for F in Fs] + [np.eye(n)]
    Qs = [Dm * Q * d[None, :] for Q in Qs] + [np.zeros((n, n))]
    xs, P, _, _ = rts_smoother(X * d, Ps * (d[:, None] * d[None, :]), Fs, Qs)
    return xs / d, P / (d[:, None] * d[None, :])
