"""The compiled twins of ``qr.frames`` (numba), for the filters' fast path, the plant and the rollout.

Same conventions as ``qr.frames`` (quaternion scalar first, body → world; rotation vectors as scipy's
``from_rotvec`` / ``as_rotvec``): one home for the compiled quaternion algebra, checked against the
scipy versions in tests/core/test_frames.py.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(cache=True)
def quat_to_R(q):
    w, x, y, z = q[0], q[1], q[2], q[3]
    R = np.empty((3, 3))
    R[0, 0] = 1 - 2 * (y * y + z * z)
    R[0, 1] = 2 * (x * y - w * z)
    R[0, 2] = 2 * (x * z + w * y)
    R[1, 0] = 2 * (x * y + w * z)
    R[1, 1] = 1 - 2 * (x * x + z * z)
    R[1, 2] = 2 * (y * z - w * x)
    R[2, 0] = 2 * (x * z - w * y)
    R[2, 1] = 2 * (y * z + w * x)
    R[2, 2] = 1 - 2 * (x * x + y * y)
    return R


@nb.njit(cache=True, inline="always")
def R_entries(q0, q1, q2, q3):
    """The nine entries of quat_to_R, row by row, as scalars (no array: for the inner loops)."""
    return (1 - 2 * (q2 * q2 + q3 * q3), 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2),
            2 * (q1 * q2 + q0 * q3), 1 - 2 * (q1 * q1 + q3 * q3), 2 * (q2 * q3 - q0 * q1),
            2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), 1 - 2 * (q1 * q1 + q2 * q2))


@nb.njit(cache=True)
def cross(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


@nb.njit(cache=True)
def matvec(A, x):
    """``A @ x`` summed in index order: numba's ``@`` calls BLAS, whose kernels (chosen per processor)
    round differently, and a simulated flight must be the same file on every machine."""
    out = np.zeros(A.shape[0])
    for i in range(A.shape[0]):
        acc = 0.0
        for j in range(A.shape[1]):
            acc += A[i, j] * x[j]
        out[i] = acc
    return out


@nb.njit(cache=True)
def qmul_s(a0, a1, a2, a3, b0, b1, b2, b3):
    """``a ⊗ b`` on scalars (no array: for the filters' inner loops)."""
    return (a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
            a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
            a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0)


@nb.njit(cache=True)
def qexp_s(p0, p1, p2):
    """Unit quaternion of a rotation vector (scipy's ``from_rotvec`` series below 1e-3 rad), on scalars."""
    th = math.sqrt(p0**2 + p1**2 + p2**2)
    if th <= 1e-3:
        s = 0.5 - th**2 / 48 + th**4 / 3840
    else:
        s = math.sin(th / 2) / th
    return math.cos(th / 2), s * p0, s * p1, s * p2


@nb.njit(cache=True)
def qlog_s(q0, q1, q2, q3):
    """Rotation vector of a quaternion, shortest rotation (scipy's ``as_rotvec``), on scalars."""
    n = math.sqrt(q0**2 + q1**2 + q2**2 + q3**2)
    sg = -1.0 if q0 < 0 else 1.0
    w = sg * q0 / n
    v0, v1, v2 = sg * q1 / n, sg * q2 / n, sg * q3 / n
    vn = math.sqrt(v0**2 + v1**2 + v2**2)
    th = 2 * math.atan2(vn, w)
    if th <= 1e-3:
        s = 2 + th**2 / 12 + 7 * th**4 / 2880
    else:
        s = th / math.sin(th / 2)
    return s * v0, s * v1, s * v2


@nb.njit(cache=True)
def quat_angle(qa, qb):
    """Rotation angle of qa⁻¹ ⊗ qb (rad, in [0, π])."""
    d = abs(qa[0] * qb[0] + qa[1] * qb[1] + qa[2] * qb[2] + qa[3] * qb[3])
    return 2.0 * math.acos(min(d, 1.0))
