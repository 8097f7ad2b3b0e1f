"""Frame conventions: the one place that says which way is up and how attitudes rotate.

World frame z up, gravity ``[0, 0, -9.81]`` m/s^2.  Body frame x forward, y left,
z along the rotor thrust.  Attitude: Hamilton unit quaternion ``[qw, qx, qy, qz]``
(scalar first) rotating body vectors into the world frame, ``R = R(q)`` as in the
thesis eq. (4.17).  Body-frame velocity and acceleration are world vectors rotated
into the body (``v_b = R^T v_w``), not derivatives of ``v_b``.
"""

from __future__ import annotations

import numpy as np

G = 9.81
GRAVITY = np.array([0.0, 0.0, -G])


def rotation(q: np.ndarray):
    """scipy ``Rotation`` from scalar-first quaternions (N, 4) or (4,)."""
    from scipy.spatial.transform import Rotation  # on use: scipy.spatial takes ~0.3 s, a log is read without it

    return Rotation.from_quat(np.asarray(q, dtype=float), scalar_first=True)


def quat_to_rot(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) (or (3, 3)) body -> world, eq. (4.17)."""
    return rotation(q).as_matrix()


def rot_to_quat(R: np.ndarray) -> np.ndarray:
    """Scalar-first unit quaternions with ``qw >= 0``."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_quat(scalar_first=True, canonical=True)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` of scalar-first quaternions, sign kept (broadcasting).

    Written out because scipy's composition returns a canonical sign, and the
    error-state filter needs the algebraic product.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    aw, av = a[..., :1], a[..., 1:]
    bw, bv = b[..., :1], b[..., 1:]
    w = aw * bw - np.sum(av * bv, axis=-1, keepdims=True)
    v = aw * bv + bw * av + np.cross(av, bv)
    return np.concatenate([w, v], axis=-1)


def make_continuous(q: np.ndarray) -> np.ndarray:
    """Flip quaternion signs so consecutive samples stay on one hemisphere.

    ``q`` and ``-q`` are the same attitude; a filter fed a sign flip sees a jump
    of 2.  Rows with NaN (dropouts) are skipped and do not reset the reference.
    """
    q = np.array(q, dtype=float, copy=True)
    ok = np.all(np.isfinite(q), axis=1)
    idx = np.flatnonzero(ok)
    if idx.size < 2:
        return q
    qq = q[idx]
    dots = np.sum(qq[1:] * qq[:-1], axis=1)
    flips = np.concatenate([[False], dots < 0])
    sign = np.where(np.cumsum(flips) % 2 == 1, -1.0, 1.0)
    q[idx] = qq * sign[:, None]
    return q


# PX4 (and the aerospace convention ROS calls "NED"): world north-east-down, body forward-right-down.
NED_TO_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # a proper swap: its own inverse
FRD_TO_FLU = np.diag([1.0, -1.0, -1.0])  # a rotation by pi about body x: its own inverse


def from_ned_frd(p_ned: np.ndarray, q_ned_frd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions (N, 3) and attitudes (N, 4, FRD body -> NED world) in qr's frames (ENU world, FLU body).

    ``R_enu_flu = T R_ned_frd F`` with ``T`` = :data:`NED_TO_ENU`, ``F`` = :data:`FRD_TO_FLU`; rows with NaN
    stay NaN, the quaternions are made continuous; a missing position component (NaN) stays missing, the
    others are kept (the swap takes components, it does not mix them)."""
    p = np.asarray(p_ned, dtype=float)[:, [1, 0, 2]] * np.array([1.0, 1.0, -1.0])  # = p @ NED_TO_ENU.T
    q_in = np.asarray(q_ned_frd, dtype=float)
    q = np.full_like(q_in, np.nan)
    ok = np.all(np.isfinite(q_in), axis=1)
    if ok.any():
        q[ok] = rot_to_quat(NED_TO_ENU @ quat_to_rot(q_in[ok]) @ FRD_TO_FLU)
    return p, make_continuous(q)


def frd_to_flu(v: np.ndarray) -> np.ndarray:
    """Body vectors (N, 3), e.g. gyro and accelerometer samples, from FRD to FLU axes."""
    return np.asarray(v, dtype=float) @ FRD_TO_FLU


def skew(v: np.ndarray) -> np.ndarray:
    """``[v]x`` (eq. 4.2) for (3,) or (N, 3)."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1),
                     np.stack([w, z, -x], -1),
                     np.stack([-y, x, z], -1)], -2)


def to_body(R: np.ndarray, v_w: np.ndarray) -> np.ndarray:
    """``R^T v`` for stacks of rotations (N, 3, 3) and vectors (N, 3)."""
    return np.einsum("nji,nj->ni", R, v_w)


def to_world(R: np.ndarray, v_b: np.ndarray) -> np.ndarray:
    """``R v`` for stacks of rotations (N, 3, 3) and vectors (N, 3)."""
    return np.einsum("nij,nj->ni", R, v_b)


def euler_zyx(q: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (rad) for plots (intrinsic z-y-x)."""
    return rotation(q).as_euler("ZYX")[..., ::-1]
