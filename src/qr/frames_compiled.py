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


@nb.njit(cache=True)
def R_entries(q0, q1, q2, q3):
    """The nine entries of quat_to_R, row by row, as scalars (no array: for the inner loops)."""
    return (1 - 2 * (q2 * q2 + q3 * q3), 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2),
            2 * (q1 * q2 + q0 * q3), 1 - 2 * (q1 * q1 + q3 * q3), 2 * (q2 * q3 - q0 * q1),
            2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), 1 - 2 * (q1 * q1 + q2 * q2))


@nb.njit(cache=True)
def cross(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


@nb.njit(cache=True)
def qmul(a, b):
    return np.array([a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
                     a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
                     a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
                     a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]])


@nb.njit(cache=True)
def qexp(phi):
    """Unit quaternion of a rotation vector (scipy's ``from_rotvec`` series below 1e-3 rad)."""
    th = math.sqrt(phi[0] ** 2 + phi[1] ** 2 + phi[2] ** 2)
    if th <= 1e-3:
        s = 0.5 - th**2 / 48 + th**4 / 3840
    else:
        s = math.sin(th / 2) / th
    return np.array([math.cos(th / 2), s * phi[0], s * phi[1], s * phi[2]])


@nb.njit(cache=True)
def qlog(q):
    """Rotation vector of a quaternion, shortest rotation (scipy's ``as_rotvec``)."""
    n = math.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    sg = -1.0 if q[0] < 0 else 1.0
    w = sg * q[0] / n
    v = sg * q[1:] / n
    vn = math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
    th = 2 * math.atan2(vn, w)
    if th <= 1e-3:
        s = 2 + th**2 / 12 + 7 * th**4 / 2880
    else:
        s = th / math.sin(th / 2)
    return s * v


@nb.njit(cache=True)
def qconj(q):
    return np.array([q[0], -q[1], -q[2], -q[3]])


@nb.njit(cache=True)
def quat_angle(qa, qb):
    """Rotation angle of qa⁻¹ ⊗ qb (rad, in [0, π])."""
    d = abs(qa[0] * qb[0] + qa[1] * qb[1] + qa[2] * qb[2] + qa[3] * qb[3])
    return 2.0 * math.acos(min(d, 1.0))
