"""Compiled small dense linear algebra shared by the filters and the identification: a Cholesky factor
and a solve through it, allocation-free (the callers pass their scratch arrays: they run per sample or
per bootstrap replicate, where a temporary costs more than the arithmetic)."""

from __future__ import annotations

import math

import numba as nb
import numpy as np


def kernel_array(a) -> np.ndarray:
    """``a`` as the one array type the compiled kernels are given: float64, C order, writable (copied only
    if it is not).  numba compiles a kernel once per argument type, and a frame read from Parquet hands out
    read-only, Fortran-ordered columns where a built one hands out C-ordered ones: each kind was a further
    compilation of the same kernel (seconds each, in every fresh checkout).  The values are the same."""
    return np.require(a, np.float64, ("C", "W"))


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


@nb.njit(cache=True)
def symmetric_eigen(A, w, V, sweeps=100, tol=1e-15):
    """Eigenvalues ``w`` (ascending) and eigenvectors (columns of ``V``) of the symmetric ``A`` by cyclic
    Jacobi rotations in a fixed order: the same digits under any BLAS kernel or thread count (the
    refinement decides from them which parameter directions the data fix).  ``A`` is not changed."""
    n = A.shape[0]
    M = A.copy()
    for i in range(n):
        for j in range(n):
            V[i, j] = 1.0 if i == j else 0.0
    scale = 0.0
    for i in range(n):
        for j in range(n):
            scale += M[i, j] * M[i, j]
    for _ in range(sweeps):
        off = 0.0
        for p in range(n):
            for q in range(p + 1, n):
                off += M[p, q] * M[p, q]
        if off <= tol * tol * scale:
            break
        for p in range(n):
            for q in range(p + 1, n):
                if M[p, q] == 0.0:
                    continue
                theta = (M[q, q] - M[p, p]) / (2.0 * M[p, q])
                t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(n):  # columns p, q
                    mkp, mkq = M[k, p], M[k, q]
                    M[k, p] = c * mkp - s * mkq
                    M[k, q] = s * mkp + c * mkq
                for k in range(n):  # rows p, q
                    mpk, mqk = M[p, k], M[q, k]
                    M[p, k] = c * mpk - s * mqk
                    M[q, k] = s * mpk + c * mqk
                for k in range(n):
                    vkp, vkq = V[k, p], V[k, q]
                    V[k, p] = c * vkp - s * vkq
                    V[k, q] = s * vkp + c * vkq
    for i in range(n):
        w[i] = M[i, i]
    for i in range(1, n):  # ascending (insertion sort, columns along)
        j = i
        while j > 0 and w[j - 1] > w[j]:
            w[j - 1], w[j] = w[j], w[j - 1]
            for k in range(n):
                V[k, j - 1], V[k, j] = V[k, j], V[k, j - 1]
            j -= 1


@nb.njit(cache=True)
def eigen_inverse(V, w, out):
    """``out = V diag(1/w) Vᵀ`` over the eigenpairs with ``w > 0`` (a zero in ``w``: the direction left out,
    the pseudo-inverse's rule).  Loops in a fixed order: the same bits on any BLAS."""
    n = V.shape[0]
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                if w[k] > 0.0:
                    s += V[i, k] * V[j, k] / w[k]
            out[i, j] = s


@nb.njit(cache=True)
def product_nt(A, B, out):
    """``out = A Bᵀ`` (square, fixed summation order)."""
    n = A.shape[0]
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += A[i, k] * B[j, k]
            out[i, j] = s


def congruence(M, B, out):
    """``out = M B Mᵀ`` (square, fixed summation order: the same bits on any BLAS)."""
    T = np.empty_like(out)
    product_nt(M, np.ascontiguousarray(B.T), T)
    product_nt(T, M, out)
