"""Compiled small dense linear algebra shared by the filters and the identification: a Cholesky factor
and a solve through it, allocation-free (the callers pass their scratch arrays: they run per sample or
per bootstrap replicate, where a temporary costs more than the arithmetic)."""

from __future__ import annotations

import math

import numba as nb


@nb.njit(cache=True)
def cholesky(A, L):
    """``A = L Lᵀ`` into the lower triangle of ``L``; False where ``A`` is not numerically positive
    definite (``L`` then undefined)."""
    n = A.shape[0]
    for j in range(n):
        s = A[j, j]
        for l in range(j):
            s -= L[j, l] * L[j, l]
        if not s > 0.0:
            return False
        L[j, j] = math.sqrt(s)
        for i in range(j + 1, n):
            s = A[i, j]
            for l in range(j):
                s -= L[i, l] * L[j, l]
            L[i, j] = s / L[j, j]
    return True


@nb.njit(cache=True)
def cholesky_solve(A, B, L, X):
    """``X = A⁻¹ B`` for a symmetric positive-definite ``A``; False (and ``X`` undefined) if ``A`` is not
    numerically positive definite.  Less than half the work of an inverse."""
    if not cholesky(A, L):
        return False
    n, m = A.shape[0], B.shape[1]
    for i in range(n):  # L Y = B
        for c in range(m):
            X[i, c] = B[i, c]
        for l in range(i):
            f = L[i, l]
            for c in range(m):
                X[i, c] -= f * X[l, c]
        for c in range(m):
            X[i, c] /= L[i, i]
    for i in range(n - 1, -1, -1):  # Lᵀ X = Y
        for l in range(i + 1, n):
            f = L[l, i]
            for c in range(m):
                X[i, c] -= f * X[l, c]
        for c in range(m):
            X[i, c] /= L[i, i]
    return True
