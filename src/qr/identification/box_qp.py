"""Least squares within bounds from normal equations: min ½xᵀGx − hᵀx, lb ≤ x ≤ ub, G positive definite.

The selection solves tens of thousands of these (p ≤ ~12, one per bootstrap replicate that leaves
the bounds); scipy's ``lsq_linear`` costs ~0.2 ms a call in Python overhead, this compiled primal
active-set method a few µs (benchmarks/diagnose.py).  It returns the same minimiser (the problem is
strictly convex); tests/diagnose/test_identification.py checks it against ``lsq_linear`` (BVLS).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..linalg_compiled import cholesky, cholesky_solve


@nb.njit(cache=True)
def _box_qp(G, h, lb, ub, x0):
    p = h.size
    x = np.minimum(np.maximum(x0, lb), ub)
    # 0 free, -1 held at lb, +1 held at ub
    state = np.zeros(p, np.int64)
    for i in range(p):
        if x[i] <= lb[i]:
            state[i] = -1
        elif x[i] >= ub[i]:
            state[i] = 1
    tol = 1e-12 * max(np.abs(h).max(), 1.0)
    for _ in range(20 * p + 20):
        free = np.flatnonzero(state == 0)
        y = x.copy()
        if free.size:
            rhs = h[free] - G[free] @ x + G[free][:, free] @ x[free]
            y[free] = np.linalg.solve(G[free][:, free], rhs)
        # a step towards y until the first bound it meets
        alpha, hit = 1.0, -1
        for i in free:
            if y[i] < lb[i]:
                a = (lb[i] - x[i]) / (y[i] - x[i])
                if a < alpha:
                    alpha, hit = a, i
            elif y[i] > ub[i]:
                a = (ub[i] - x[i]) / (y[i] - x[i])
                if a < alpha:
                    alpha, hit = a, i
        if hit >= 0:
            for i in free:
                x[i] += alpha * (y[i] - x[i])
            if y[hit] < lb[hit]:
                x[hit], state[hit] = lb[hit], -1
            else:
                x[hit], state[hit] = ub[hit], 1
            continue
        x = y
        # KKT: a variable held at lb needs a non-negative gradient, at ub a non-positive one
        g = G @ x - h
        worst, j = tol, -1
        for i in range(p):
            v = -g[i] if state[i] == -1 else (g[i] if state[i] == 1 else 0.0)
            if v > worst:
                worst, j = v, i
        if j < 0:
            return x, True
        state[j] = 0
    return x, False


@nb.njit(cache=True)
def _box_qp_many(G, h, lb, ub, x0, out):
    ok = np.empty(h.shape[0], np.bool_)
    for k in range(h.shape[0]):
        x, ok[k] = _box_qp(G[k], h[k], lb[k], ub[k], x0[k])
        out[k] = x
    return ok


@nb.njit(cache=True)
def scaled_solve_many(G, h, ridge, floor, Gn, d, out):
    """Each system of a stack scaled to a unit diagonal (``Gn = G / d dᵀ`` plus ``ridge``) and solved
    by Cholesky; False where ``Gn`` has an eigenvalue below ``floor`` (``Gn - floor I`` has no Cholesky
    factor), left for the caller to repair."""
    n, p = h.shape
    ok = np.empty(n, np.bool_)
    L = np.empty((p, p))
    shifted = np.empty((p, p))
    rhs, x = np.empty((p, 1)), np.empty((p, 1))
    for k in range(n):
        top = 0.0
        for i in range(p):
            top = max(top, abs(G[k, i, i]))
        low = 1e-12 * max(top, 1e-300)
        for i in range(p):
            d[k, i] = np.sqrt(max(G[k, i, i], low))
        for i in range(p):
            for j in range(p):
                Gn[k, i, j] = G[k, i, j] / (d[k, i] * d[k, j])
                shifted[i, j] = Gn[k, i, j]
            Gn[k, i, i] += ridge
            shifted[i, i] += ridge - floor
            rhs[i, 0] = h[k, i] / d[k, i]
        ok[k] = cholesky(shifted, L) and cholesky_solve(Gn[k], rhs, L, x)
        if ok[k]:
            for i in range(p):
                out[k, i] = x[i, 0] / d[k, i]
    return ok


def box_qp_many(G: np.ndarray, h: np.ndarray, lb: np.ndarray, ub: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """``box_qp`` for a stack (n, p, p), (n, p); bounds (p,) or (n, p)."""
    G, h = np.ascontiguousarray(G, float), np.ascontiguousarray(h, float)
    lb = np.ascontiguousarray(np.broadcast_to(np.asarray(lb, float), h.shape))
    ub = np.ascontiguousarray(np.broadcast_to(np.asarray(ub, float), h.shape))
    out = np.empty_like(h)
    ok = _box_qp_many(G, h, lb, ub, np.ascontiguousarray(x0, float), out)
    for k in np.flatnonzero(~ok):
        out[k] = _bvls(G[k], h[k], lb[k], ub[k])
    return out


def box_qp(G: np.ndarray, h: np.ndarray, lb: np.ndarray, ub: np.ndarray, x0: np.ndarray | None = None
           ) -> np.ndarray:
    """The bounded minimiser; scipy's BVLS in the rare case the active-set loop does not settle."""
    G, h = np.ascontiguousarray(G, float), np.ascontiguousarray(h, float)
    lb = np.broadcast_to(np.asarray(lb, float), h.shape).copy()
    ub = np.broadcast_to(np.asarray(ub, float), h.shape).copy()
    x, ok = _box_qp(G, h, lb, ub, np.zeros_like(h) if x0 is None else np.asarray(x0, float).copy())
    return x if ok else _bvls(G, h, lb, ub)


def _bvls(G, h, lb, ub) -> np.ndarray:
    """scipy's BVLS on the same quadratic: min ||Lᵀx − L⁻¹h||² with G = L Lᵀ."""
    from scipy.linalg import cho_factor, solve_triangular
    from scipy.optimize import lsq_linear

    L = np.tril(cho_factor(G, lower=True)[0])
    return lsq_linear(L.T, solve_triangular(L, h, lower=True), bounds=(lb, ub), method="bvls").x
