"""The fast path: the same filters and smoothers as compiled loops (numba).

Same equations and operation order as the filterpy reference (Joseph-form
update, smoother on equilibrated states), so the two agree to rounding error
(tested to 1e-9).  The linear filters run vectorised over channels that share
a dropout pattern (the three position axes, the four rotors): one covariance
recursion serves them all, since Φ, Q, H and R are the same for each.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ..frames_compiled import R_entries, qexp_s, qlog_s, qmul_s
from ..linalg_compiled import cholesky_solve as _cholesky_solve

# ---- integrator chains ---------------------------------------------------------------


@nb.njit(cache=True)
def _fact(n):
    f = 1.0
    for i in range(2, n + 1):
        f *= i
    return f


@nb.njit(cache=True)
def chain_q_into(m, dt, q, exact, Q):
    """``Q`` := the chain's discrete process noise (written in place: the filters call it every sample)."""
    if not exact:
        for i in range(m):
            for j in range(m):
                Q[i, j] = 0.0
        Q[m - 1, m - 1] = q
        return
    for i in range(m):
        for j in range(m):
            a, b = m - 1 - i, m - 1 - j
            Q[i, j] = q * dt ** (a + b + 1) / (_fact(a) * _fact(b) * (a + b + 1))


@nb.njit(cache=True)
def _chain_coeffs(m, dt, out):
    """``out[d] = dt^d / d!``: the entries of Φ on its d-th superdiagonal."""
    out[0] = 1.0
    for d in range(1, m):
        out[d] = dt**d / _fact(d)


@nb.njit(cache=True)
def _chain_predict(P, c, T, out):
    """``out = Φ P Φᵀ`` for the upper-triangular Toeplitz Φ with superdiagonals ``c``."""
    m = P.shape[0]
    for i in range(m):
        for j in range(m):
            s = 0.0
            for l in range(i, m):
                s += c[l - i] * P[l, j]
            T[i, j] = s
    for i in range(m):
        for j in range(m):
            s = 0.0
            for l in range(j, m):
                s += T[i, l] * c[l - j]
            out[i, j] = s


@nb.njit(cache=True, nogil=True)
def chain_forward(t, y, valid, q, r, exact, x0, P0, store):
    """Kalman filter of ``c`` channels sharing one covariance; ``y`` (N, c), ``valid`` (N,).

    Returns means (N, c, m), variances (N, m), covariances (N or 1, m, m),
    NIS (N, c) and log S (N,) (NaN without an update).
    """
    N, c = y.shape
    m = P0.shape[0]
    X = np.empty((N, c, m))
    V = np.empty((N, m))
    Ps = np.empty((N if store else 1, m, m))
    nis = np.full((N, c), np.nan)
    logS = np.full(N, np.nan)
    x = x0.copy()
    P = P0.copy()
    P2, T = np.empty((m, m)), np.empty((m, m))
    co, xn, K, Q = np.empty(m), np.empty(m), np.empty(m), np.empty((m, m))
    last_dt = np.nan
    for k in range(N):
        if k > 0:
            dt = t[k] - t[k - 1]
            if dt != last_dt:  # uniform stamps: the powers of dt once, not every sample
                _chain_coeffs(m, dt, co)
                chain_q_into(m, dt, q, exact, Q)
                last_dt = dt
            for ch in range(c):
                for i in range(m):
                    s = 0.0
                    for j in range(i, m):
                        s += co[j - i] * x[ch, j]
                    xn[i] = s
                x[ch] = xn
            _chain_predict(P, co, T, P2)
            for i in range(m):
                for j in range(m):
                    P[i, j] = P2[i, j] + Q[i, j]
        if valid[k]:
            S = P[0, 0] + r
            for i in range(m):
                K[i] = P[i, 0] / S
            for ch in range(c):
                e = y[k, ch] - x[ch, 0]
                for i in range(m):
                    x[ch, i] += K[i] * e
                nis[k, ch] = e * e / S
            logS[k] = math.log(S)
            # Joseph form (I - K H) P (I - K H)ᵀ + K r Kᵀ with H = e₀ᵀ
            for i in range(m):
                for j in range(m):
                    T[i, j] = P[i, j] - K[i] * P[0, j]
            for i in range(m):
                for j in range(m):
                    P[i, j] = T[i, j] - T[i, 0] * K[j] + r * K[i] * K[j]
        X[k] = x
        for i in range(m):
            V[k, i] = P[i, i]
        Ps[k if store else 0] = P
    return X, V, Ps, nis, logS


@nb.njit(cache=True)
def _inverse(A, out, W):
    """``out = A⁻¹`` by Gauss–Jordan with partial pivoting (small matrices, no allocation)."""
    n = A.shape[0]
    for i in range(n):
        for j in range(n):
            W[i, j] = A[i, j]
            out[i, j] = 1.0 if i == j else 0.0
    for col in range(n):
        piv = col
        for r in range(col + 1, n):
            if abs(W[r, col]) > abs(W[piv, col]):
                piv = r
        if piv != col:
            for j in range(n):
                W[col, j], W[piv, j] = W[piv, j], W[col, j]
                out[col, j], out[piv, j] = out[piv, j], out[col, j]
        p = W[col, col]
        for j in range(n):
            W[col, j] /= p
            out[col, j] /= p
        for r in range(n):
            f = W[r, col]
            if r != col and f != 0.0:
                for j in range(n):
                    W[r, j] -= f * W[col, j]
                    out[r, j] -= f * out[col, j]


# The small matrix products below run in i-l-j order (row updates): the same sums in the same order
# as the textbook i-j-l dot products, but the inner loop is contiguous and vectorises.


@nb.njit(cache=True)
def _product(A, B, out, a_transposed):
    """``out = A B`` (``Aᵀ B`` if ``a_transposed``), in row order."""
    n = out.shape[0]
    for i in range(n):
        for j in range(n):
            out[i, j] = 0.0
        for l in range(n):
            f = A[l, i] if a_transposed else A[i, l]
            for j in range(n):
                out[i, j] += f * B[l, j]


@nb.njit(cache=True)
def _rts_step(Pk, T, pP, Pnext, dd, K, scratch, out):
    """Smoother gain ``K = P Φᵀ (P⁻)⁻¹`` (``T = Φ P``) and ``out = (P + K (P_s,next - P⁻) Kᵀ) / dd``.

    ``Pk``, ``T``, ``pP`` are equilibrated (``D · D``); ``Pnext`` is the next smoothed covariance, unscaled.
    ``Kᵀ = (P⁻)⁻¹ Φ P`` by Cholesky (an inverse with pivoting where ``P⁻`` is not numerically positive
    definite); ``out`` is symmetric by construction.  ``scratch``: (4, n, n).
    """
    n = Pk.shape[0]
    L, Kt, D, W = scratch[0], scratch[1], scratch[2], scratch[3]
    if _cholesky_solve(pP, T, L, Kt):
        for i in range(n):
            for j in range(n):
                K[i, j] = Kt[j, i]
    else:
        _inverse(pP, L, W)
        _product(T, L, K, True)  # K = Tᵀ (P⁻)⁻¹
        for i in range(n):
            for j in range(n):
                Kt[j, i] = K[i, j]
    for i in range(n):
        for j in range(n):
            D[i, j] = Pnext[i, j] * dd[i, j] - pP[i, j]
    _product(K, D, W, False)
    row = L[0]  # L is free again: one row of W Kᵀ
    for i in range(n):
        for j in range(i, n):
            row[j] = 0.0
        for l in range(n):
            f = W[i, l]
            for j in range(i, n):
                row[j] += f * Kt[l, j]
        for j in range(i, n):
            out[i, j] = (Pk[i, j] + row[j]) / dd[i, j]
            out[j, i] = out[i, j]


@nb.njit(cache=True, nogil=True)
def chain_smooth(t, X, Ps, q, exact, d):
    """RTS on the equilibrated states ``d * x``; overwrites ``X`` (N, c, m) and ``Ps`` (N, m, m)."""
    N, c, m = X.shape
    dd = np.outer(d, d)
    co, r = np.empty(m), np.empty(m)
    T, pP, Pk, K, Q = np.empty((m, m)), np.empty((m, m)), np.empty((m, m)), np.empty((m, m)), np.empty((m, m))
    scratch = np.empty((4, m, m))
    last_dt = np.nan
    for k in range(N - 2, -1, -1):
        dt = t[k + 1] - t[k]
        if dt != last_dt:
            _chain_coeffs(m, dt, co)
            chain_q_into(m, dt, q, exact, Q)
            last_dt = dt
        _chain_predict(Ps[k], co, T, pP)
        for i in range(m):
            for j in range(m):
                Pk[i, j] = Ps[k, i, j] * dd[i, j]
                T[i, j] *= dd[i, j]  # D Φ P D = (D Φ D⁻¹)(D P D)
                pP[i, j] = (pP[i, j] + Q[i, j]) * dd[i, j]
        _rts_step(Pk, T, pP, Ps[k + 1], dd, K, scratch, Ps[k])
        for ch in range(c):
            for i in range(m):  # residual: smoothed next minus predicted
                s = 0.0
                for j in range(i, m):
                    s += co[j - i] * X[k, ch, j]
                r[i] = (X[k + 1, ch, i] - s) * d[i]
            for i in range(m):
                s = 0.0
                for j in range(m):
                    s += K[i, j] * r[j]
                X[k, ch, i] += s / d[i]


# ---- attitude ESKF -------------------------------------------------------------------


@nb.njit(cache=True)
def eskf_coeffs(dt, exact, c):
    """Chain coefficients of the (corrected) eq. 4.19 Φ.

    ``c[0, d]``: the δθ row (times Rᵀ); ``c[1, d]``: the rate rows.  The
    second-order Φ = I + F dt + F² dt²/2 has no δθ–δα̇ term; the exact one has
    ``F³ dt³/6``.
    """
    h = dt
    for row in range(2):
        c[row, 0] = 1.0
        c[row, 1] = h
        c[row, 2] = h * h / 2
        c[row, 3] = h**3 / 6
    if not exact:
        c[0, 3] = 0.0


@nb.njit(cache=True)
def eskf_predict(P, R, c, T, out):
    """``out = Φ P Φᵀ`` and ``T = Φ P`` using Φ's block structure (no 12×12 products)."""
    for j in range(12):  # T = Φ P, row blocks
        for a in range(3):
            s = P[a, j]
            for bj in range(1, 4):
                for b in range(3):
                    s += c[0, bj] * R[b, a] * P[3 * bj + b, j]
            T[a, j] = s
        for bi in range(1, 4):
            for a in range(3):
                s = 0.0
                for bj in range(bi, 4):
                    s += c[1, bj - bi] * P[3 * bj + a, j]
                T[3 * bi + a, j] = s
    for i in range(12):  # out = T Φᵀ, column blocks
        for a in range(3):
            s = T[i, a]
            for bj in range(1, 4):
                for b in range(3):
                    s += T[i, 3 * bj + b] * c[0, bj] * R[b, a]
            out[i, a] = s
        for bi in range(1, 4):
            for a in range(3):
                s = 0.0
                for bj in range(bi, 4):
                    s += T[i, 3 * bj + a] * c[1, bj - bi]
                out[i, 3 * bi + a] = s


@nb.njit(cache=True)
def eskf_add_q(P, R, dt, qd, exact, Qc):
    """``P += Q_d``: eq. 4.20 (``G Q Gᵀ dt²``) or the exact integral with its δθ rows rotated by Rᵀ
    (``Qc``: the chain's unit-intensity noise over ``dt``, ``chain_q_into(4, dt, 1, True, Qc)``)."""
    if not exact:
        for a in range(3):
            P[9 + a, 9 + a] += qd[a] * dt * dt
        return
    for a in range(3):
        for b in range(3):
            s = 0.0
            for k in range(3):
                s += R[k, a] * qd[k] * R[k, b]
            P[a, b] += Qc[0, 0] * s
    for bi in range(1, 4):
        for a in range(3):
            for bj in range(1, 4):
                P[3 * bi + a, 3 * bj + a] += Qc[bi, bj] * qd[a]
            for b in range(3):
                v = R[a, b] * Qc[0, bi] * qd[a]  # (Rᵀ)[b, a] q_a: δθ_b with rate block bi, axis a
                P[b, 3 * bi + a] += v
                P[3 * bi + a, b] += v


@nb.njit(cache=True)
def set_R(quat, R):
    """``R`` := the rotation matrix of ``quat`` (in place)."""
    (R[0, 0], R[0, 1], R[0, 2], R[1, 0], R[1, 1], R[1, 2],
     R[2, 0], R[2, 1], R[2, 2]) = R_entries(quat[0], quat[1], quat[2], quat[3])


@nb.njit(cache=True)
def eskf_propagate(quat, psi, dt, exact, qout, pout):
    """Nominal mean one step ahead into ``qout``, ``pout`` (may be ``quat``, ``psi``); returns the
    rotation angle of the step."""
    h2 = dt * dt / 2
    p0 = psi[0] * dt + psi[3] * h2
    p1 = psi[1] * dt + psi[4] * h2
    p2 = psi[2] * dt + psi[5] * h2
    if exact:
        h3 = dt**3 / 6
        p0, p1, p2 = p0 + psi[6] * h3, p1 + psi[7] * h3, p2 + psi[8] * h3
    e0, e1, e2, e3 = qexp_s(p0, p1, p2)
    qout[0], qout[1], qout[2], qout[3] = qmul_s(e0, e1, e2, e3, quat[0], quat[1], quat[2], quat[3])
    for a in range(3):
        pout[a] = psi[a] + psi[3 + a] * dt + psi[6 + a] * h2
        pout[3 + a] = psi[3 + a] + psi[6 + a] * dt
        pout[6 + a] = psi[6 + a]
    return math.sqrt(p0**2 + p1**2 + p2**2)


@nb.njit(cache=True)
def eskf_inject(quat, psi, dx):
    """``q ⊗ exp(δθ)`` (normalised) and the rates plus their corrections, in place."""
    e0, e1, e2, e3 = qexp_s(dx[0], dx[1], dx[2])
    q0, q1, q2, q3 = qmul_s(quat[0], quat[1], quat[2], quat[3], e0, e1, e2, e3)
    n = math.sqrt(q0**2 + q1**2 + q2**2 + q3**2)
    quat[0], quat[1], quat[2], quat[3] = q0 / n, q1 / n, q2 / n, q3 / n
    for i in range(9):
        psi[i] += dx[3 + i]


@nb.njit(cache=True)
def attitude_error(qa, qb, e):
    """``e`` := ``log(qa⁻¹ ⊗ qb)``, the body rotation vector from ``qa`` to ``qb`` (eq. 4.24)."""
    e[0], e[1], e[2] = qlog_s(*qmul_s(qa[0], -qa[1], -qa[2], -qa[3], qb[0], qb[1], qb[2], qb[3]))


@nb.njit(cache=True)
def _inv3(S, out):
    """Inverse and determinant of a 3×3 matrix (adjugate)."""
    a, b, c = S[0, 0], S[0, 1], S[0, 2]
    d, e, f = S[1, 0], S[1, 1], S[1, 2]
    g, h, i = S[2, 0], S[2, 1], S[2, 2]
    A, B, C = e * i - f * h, -(d * i - f * g), d * h - e * g
    det = a * A + b * B + c * C
    out[0, 0], out[1, 0], out[2, 0] = A / det, B / det, C / det
    out[0, 1], out[1, 1], out[2, 1] = -(b * i - c * h) / det, (a * i - c * g) / det, -(a * h - b * g) / det
    out[0, 2], out[1, 2], out[2, 2] = (b * f - c * e) / det, -(a * f - c * d) / det, (a * e - b * d) / det
    return det


@nb.njit(cache=True)
def gyro_update(quat, psi, P, zg, rg, R):
    """A gyro sample ``zg`` (body rate, bias removed) with variance ``rg`` per axis, in place
    (``R``: 3 × 3 scratch).

    ``ω_b = Rᵀ ω`` with ``R = R̂ exp(δθ)``: ``H = [[ω̂_b]×, R̂ᵀ, 0, 0]`` to first order.
    Joseph-form update, as filterpy's ``update(z, R, H)``.
    """
    set_R(quat, R)
    wb = np.zeros(3)
    for a in range(3):
        wb[a] = R[0, a] * psi[0] + R[1, a] * psi[1] + R[2, a] * psi[2]
    H = np.zeros((3, 12))
    H[0, 1], H[0, 2] = -wb[2], wb[1]
    H[1, 0], H[1, 2] = wb[2], -wb[0]
    H[2, 0], H[2, 1] = -wb[1], wb[0]
    for a in range(3):
        for b in range(3):
            H[a, 3 + b] = R[b, a]
    PHt = P @ H.T
    S = H @ PHt
    for a in range(3):
        S[a, a] += rg
    SI = np.empty((3, 3))
    _inv3(S, SI)
    K = PHt @ SI
    dx = K @ (zg - wb)
    IKH = np.eye(12) - K @ H
    P[:, :] = IKH @ P @ IKH.T + rg * (K @ K.T)
    eskf_inject(quat, psi, dx)


@nb.njit(cache=True, nogil=True)
def eskf_forward(t, zq, valid, qd, r, exact, quat0, psi0, P0, store, reset_angle, zg, gvalid, rg):
    """The attitude ESKF.  Returns quaternions (N, 4), world rates (N, 9), covariances
    (N or 1, 12, 12), variances (N, 12), the ω and α blocks (N, 2, 3, 3), NIS (N,), log det S (N,)
    and the samples where the track was lost and the filter restarted (innovation angle above
    ``reset_angle``, or a predicted rotation between samples above it; never if it is <= 0).
    ``zg`` (N, 3): gyro samples fused where ``gvalid`` (:func:`gyro_update`).  Allocation-free per
    sample (except the gyro update): small arrays cost more than the arithmetic."""
    N = zq.shape[0]
    resets = np.zeros(N, dtype=np.bool_)
    QT = np.empty((N, 4))
    PSI = np.empty((N, 9))
    Ps = np.empty((N if store else 1, 12, 12))
    V = np.empty((N, 12))
    Bl = np.empty((N, 2, 3, 3))
    nis = np.full(N, np.nan)
    logdet = np.full(N, np.nan)
    quat = quat0.copy()
    psi = psi0.copy()
    P = P0.copy()
    T = np.empty((12, 12))
    c = np.empty((2, 4))
    R, Qc = np.empty((3, 3)), np.empty((4, 4))
    S, SI, K = np.empty((3, 3)), np.empty((3, 3)), np.empty((12, 3))
    dx, e = np.empty(12), np.empty(3)
    lost = False
    last_dt = np.nan
    for k in range(N):
        if k > 0:
            dt = t[k] - t[k - 1]
            set_R(quat, R)
            if dt != last_dt:
                eskf_coeffs(dt, exact, c)
                chain_q_into(4, dt, 1.0, True, Qc)
                last_dt = dt
            eskf_predict(P, R, c, T, P)  # eq. 4.22 (out may alias P: T holds Φ P)
            eskf_add_q(P, R, dt, qd, exact, Qc)
            angle = eskf_propagate(quat, psi, dt, exact, quat, psi)
            lost = lost or (reset_angle > 0 and angle > reset_angle)
        if valid[k]:
            attitude_error(quat, zq[k], e)  # eq. 4.24
            for a in range(3):
                for b in range(3):
                    S[a, b] = P[a, b] + (r if a == b else 0.0)
            det = _inv3(S, SI)
            s = 0.0
            for a in range(3):
                for b in range(3):
                    s += e[a] * SI[a, b] * e[b]
            nis[k] = s
            logdet[k] = math.log(det)
            if lost or (reset_angle > 0 and math.sqrt(e[0] ** 2 + e[1] ** 2 + e[2] ** 2) > reset_angle):
                n = math.sqrt(zq[k, 0] ** 2 + zq[k, 1] ** 2 + zq[k, 2] ** 2 + zq[k, 3] ** 2)
                for i in range(4):
                    quat[i] = zq[k, i] / n
                psi[:] = 0.0  # track lost: restart at the measurement
                P[:, :] = P0
                resets[k] = True
                lost = False
            else:
                for i in range(12):  # K = P Hᵀ S⁻¹ (eq. 4.25)
                    for b in range(3):
                        K[i, b] = P[i, 0] * SI[0, b] + P[i, 1] * SI[1, b] + P[i, 2] * SI[2, b]
                for i in range(12):
                    dx[i] = K[i, 0] * e[0] + K[i, 1] * e[1] + K[i, 2] * e[2]
                eskf_inject(quat, psi, dx)  # eq. 4.27a-d
                for i in range(12):  # Joseph form of eq. 4.27e
                    for j in range(12):
                        T[i, j] = P[i, j] - (K[i, 0] * P[0, j] + K[i, 1] * P[1, j] + K[i, 2] * P[2, j])
                for i in range(12):
                    for j in range(12):
                        P[i, j] = (T[i, j] - (T[i, 0] * K[j, 0] + T[i, 1] * K[j, 1] + T[i, 2] * K[j, 2])
                                   + r * (K[i, 0] * K[j, 0] + K[i, 1] * K[j, 1] + K[i, 2] * K[j, 2]))
        if gvalid[k] and not resets[k]:
            gyro_update(quat, psi, P, zg[k], rg, R)
        QT[k] = quat
        PSI[k] = psi
        if store:
            Ps[k] = P
        for i in range(12):
            V[k, i] = P[i, i]
        for a in range(3):
            for b in range(3):
                Bl[k, 0, a, b] = P[3 + a, 3 + b]
                Bl[k, 1, a, b] = P[6 + a, 6 + b]
    return QT, PSI, Ps, V, Bl, nis, logdet, resets


@nb.njit(cache=True, nogil=True)
def eskf_smooth(t, QT, PSI, Ps, qd, exact, d, resets):
    """RTS on the equilibrated error state ``d * δx``; overwrites ``QT``, ``PSI``, ``Ps`` (filtered in,
    smoothed out).  A restart (``resets[k+1]``) cuts the chain: samples before it form their own segment."""
    N = QT.shape[0]
    dd = np.outer(d, d)
    c = np.empty((2, 4))
    T, pP, Pk = np.empty((12, 12)), np.empty((12, 12)), np.empty((12, 12))
    Qs, C = np.empty((12, 12)), np.empty((12, 12))
    R, Qc = np.empty((3, 3)), np.empty((4, 4))
    scratch = np.empty((4, 12, 12))
    delta, dx = np.empty(12), np.empty(12)
    q_pred, psi_pred = np.empty(4), np.empty(9)
    last_dt = np.nan
    for k in range(N - 2, -1, -1):
        if resets[k + 1]:
            continue
        dt = t[k + 1] - t[k]
        set_R(QT[k], R)
        if dt != last_dt:
            eskf_coeffs(dt, exact, c)
            chain_q_into(4, dt, 1.0, True, Qc)
            last_dt = dt
        eskf_predict(Ps[k], R, c, T, pP)
        Qs[:, :] = 0.0
        eskf_add_q(Qs, R, dt, qd, exact, Qc)
        for i in range(12):
            for j in range(12):
                Pk[i, j] = Ps[k, i, j] * dd[i, j]
                T[i, j] *= dd[i, j]
                pP[i, j] = (pP[i, j] + Qs[i, j]) * dd[i, j]
        eskf_propagate(QT[k], PSI[k], dt, exact, q_pred, psi_pred)
        _rts_step(Pk, T, pP, Ps[k + 1], dd, C, scratch, Ps[k])
        attitude_error(q_pred, QT[k + 1], delta)
        for i in range(9):
            delta[3 + i] = PSI[k + 1, i] - psi_pred[i]
        for i in range(12):
            s = 0.0
            for j in range(12):
                s += C[i, j] * delta[j] * d[j]
            dx[i] = s / d[i]
        eskf_inject(QT[k], PSI[k], dx)
