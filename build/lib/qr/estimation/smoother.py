"""Rauch–Tung–Striebel smoothing: the same models run backward over the filtered flight.

Offline data deserve zero-lag estimates: the forward filter's derivatives lag
the motion by roughly the inverse of its bandwidth, the smoothed ones do not,
and their errors are smaller.

- Linear filters (position, rotors): ``filterpy.kalman.rts_smoother``.
- Attitude ESKF: the same recursion on the error state, beside the filter whose
  state it shares (:func:`qr.estimation.attitude_eskf.rts_eskf`).

Both work on equilibrated states ``D x`` (:func:`equilibration`, every state
at unit typical variance): a chain's variances span ~14 orders of magnitude
(m² … (m/s³)² at 100 Hz), and the predicted covariances the backward pass
inverts drop from cond ≈ 1e7–1e12 to ≈ 1e2–1e3.
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
