"""Orientation: error-state Kalman filter on SO(3) (thesis §4.2.1.2, eqs. 4.11–4.27).

Nominal state ``[q, ω, α, α̇]``, error state ``[δθ, δω, δα, δα̇]`` (12); the rates are world-frame vectors and
the attitude error a body-frame rotation vector, as the thesis writes them (hence ``Rᵀ`` in F's δθ–δω block).
The corrections to the thesis (eqs. 4.19, 4.23) and the restart guard (:data:`RESET_DEG`): docs/filter.md.
"""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from ..frames import quat_multiply, quat_to_rot, rotation, skew
from . import chain
from .nis import Innovations
from .smoother import equilibration

THESIS_Q = 500.0 * np.array([1.0, 0.1, 1.0])  # eq. 4.16a: Q = 500 diag(1, 0.1, 1) on α̈
THESIS_R = 0.001**2  # eq. 4.16b
H = np.hstack([np.eye(3), np.zeros((3, 9))])  # eq. 4.26
G = np.vstack([np.zeros((9, 3)), np.eye(3)])  # eq. 4.21
P0_RATES = (1.0, 1e2, 1e4)  # initial variances of ω, α, α̇: (1 rad/s)², (10 rad/s²)², (100 rad/s³)²
# Not in the thesis: an innovation angle, or a predicted rotation between two samples, above this means the
# filter has lost the vehicle (a gap during a fast rotation, a marker swap): the log map aliases and ω runs
# away, so the filter restarts at the next measurement.
RESET_DEG = 90.0


def F_matrix(R: np.ndarray) -> np.ndarray:
    """Continuous error dynamics, eq. 4.18."""
    F = np.zeros((12, 12))
    F[0:3, 3:6] = R.T
    F[3:6, 6:9] = np.eye(3)
    F[6:9, 9:12] = np.eye(3)
    return F


def transition(R: np.ndarray, dt: float, discretisation: str = "thesis") -> np.ndarray:
    """Φ from eq. 4.19, corrected: ``I + F dt + F² dt²/2`` (the thesis drops the 1/2)."""
    F = F_matrix(R)
    F2 = F @ F
    Phi = np.eye(12) + F * dt + F2 * dt**2 / 2
    if discretisation == "exact":  # F⁴ = 0, so this is exp(F dt)
        Phi += F2 @ F * dt**3 / 6
    return Phi


def process_noise(R: np.ndarray, dt: float, q, discretisation: str = "thesis") -> np.ndarray:
    """``Q_d``: eq. 4.20 (``G Q Gᵀ dt²``) or the exact integral for intensity ``q`` per world axis."""
    q = np.broadcast_to(np.asarray(q, dtype=float), (3,))
    if discretisation == "thesis":
        return G @ np.diag(q) @ G.T * dt**2
    B = np.eye(12)
    B[0:3, 0:3] = R.T  # the chain's first state is the body-frame δθ
    return B @ np.kron(chain.process_noise(4, dt, 1.0, "exact"), np.diag(q)) @ B.T


def measurement_noise(r: float) -> np.ndarray:
    return r * np.eye(3)


def rot_increment(psi: np.ndarray, dt: float, discretisation: str) -> np.ndarray:
    """World rotation vector over ``dt``: the first row of the chain Φ applied to (ω, α, α̇)."""
    w, a, j = psi[0:3], psi[3:6], psi[6:9]
    phi = w * dt + a * (dt**2 / 2)
    if discretisation == "exact":
        phi = phi + j * (dt**3 / 6)
    return phi


def quat_exp(phi: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation  # on use: scipy.spatial takes ~0.1 s to import

    return Rotation.from_rotvec(phi).as_quat(scalar_first=True)


def quat_log(q: np.ndarray) -> np.ndarray:
    return rotation(q).as_rotvec()


def propagate(quat, psi, dt, discretisation):
    """Nominal mean one step ahead: ``q⁻ = exp(φ) ⊗ q`` (eq. 4.23a), ``ψ⁻ = Φ_chain ψ``."""
    q_new = quat_multiply(quat_exp(rot_increment(psi, dt, discretisation)), quat)
    psi_new = np.kron(chain.transition(3, dt), np.eye(3)) @ psi
    return q_new, psi_new


def inject(quat, psi, dx):
    """Apply an error-state correction: ``q ⊗ exp(δθ)`` (eq. 4.27a), rates additively (4.27b–d)."""
    q = quat_multiply(quat, quat_exp(dx[0:3]))
    return q / np.linalg.norm(q), psi + dx[3:12]


def boxminus(quat, psi, quat_ref, psi_ref):
    """``x ⊖ x_ref``: body rotation vector ``log(q_refᵀ q)`` (eq. 4.24) and rate differences."""
    conj = quat_ref * np.array([1.0, -1, -1, -1])
    return np.concatenate([quat_log(quat_multiply(conj, quat)), psi - psi_ref])


def initial(quat0, r):
    P0 = np.diag(np.concatenate([np.full(3, float(r)), np.repeat(P0_RATES, 3)]))
    return np.asarray(quat0, dtype=float) / np.linalg.norm(quat0), np.zeros(9), P0


def gyro_H(quat, psi) -> np.ndarray:
    """Gyro measurement matrix: ``ω_b = Rᵀ ω``, ``R = R̂ exp(δθ)`` ⇒ ``H = [[ω̂_b]×, R̂ᵀ, 0, 0]`` (first order)."""
    R = quat_to_rot(quat)
    H = np.zeros((3, 12))
    H[:, 0:3] = skew(R.T @ psi[0:3])
    H[:, 3:6] = R.T
    return H


def filter_reference(t, quat_meas, q, r, discretisation="thesis", smooth=False, progress=False,
                     reset_deg=RESET_DEG, gyro=None, r_gyro=None):
    """ESKF (and optional RTS) on filterpy: the error state's covariance lives in a ``KalmanFilter``.

    ``quat_meas`` (N, 4) with NaN rows for dropouts; ``gyro`` (N, 3), optional: body rates with the
    bias removed, variance ``r_gyro`` per axis, fused after the attitude update.  Returns quaternions
    (N, 4), world rates ψ = (ω, α, α̇) (N, 9), covariances (N, 12, 12),
    :class:`Innovations` and the restart flags (N,) (see :data:`RESET_DEG`).
    """
    from filterpy.kalman import KalmanFilter


    N = len(t)
    valid = np.all(np.isfinite(quat_meas), axis=1)
    first = int(np.argmax(valid))
    quat, psi, P0 = initial(quat_meas[first], r)
    kf = KalmanFilter(dim_x=12, dim_z=3)
    kf.P = P0
    kf.H = H
    kf.R = measurement_noise(r)
    Q_out, PSI, Ps = np.empty((N, 4)), np.empty((N, 9)), np.empty((N, 12, 12))
    resets = np.zeros(N, dtype=bool)
    nis, logdet = np.full((N, 1), np.nan), np.full((N, 1), np.nan)

    def step(k):
        dt = t[k + 1] - t[k]
        R = quat_to_rot(Q_out[k])
        q_pred, psi_pred = propagate(Q_out[k], PSI[k], dt, discretisation)
        return transition(R, dt, discretisation), process_noise(R, dt, q, discretisation), q_pred, psi_pred

    limit = np.inf if reset_deg is None else np.radians(reset_deg)
    lost = False
    for k in tqdm(range(N), desc="attitude (reference)", disable=not progress, mininterval=1.0):
        if k:
            Phi, Qd, quat, psi = step(k - 1)
            kf.x = np.zeros((12, 1))
            kf.predict(F=Phi, Q=Qd)  # eq. 4.22; the error mean stays zero
            lost = lost or np.linalg.norm(rot_increment(PSI[k - 1], t[k] - t[k - 1], discretisation)) > limit
        if valid[k]:
            e = quat_log(quat_multiply(quat * np.array([1.0, -1, -1, -1]), quat_meas[k]))  # eq. 4.24
            kf.x = np.zeros((12, 1))
            kf.update(e.reshape(3, 1))
            nis[k, 0] = (kf.y.T @ kf.SI @ kf.y).item()
            logdet[k, 0] = np.linalg.slogdet(kf.S)[1]
            if lost or np.linalg.norm(e) > limit:  # track lost: restart at the measurement
                quat, psi, kf.P = quat_meas[k] / np.linalg.norm(quat_meas[k]), np.zeros(9), P0.copy()
                resets[k], lost = True, False
            else:
                quat, psi = inject(quat, psi, kf.x[:, 0])
        if gyro is not None and np.all(np.isfinite(gyro[k])) and not resets[k]:
            Hg = gyro_H(quat, psi)
            kf.x = np.zeros((12, 1))
            kf.update((gyro[k] - Hg[:, 3:6] @ psi[0:3]).reshape(3, 1), R=r_gyro * np.eye(3), H=Hg)
            quat, psi = inject(quat, psi, kf.x[:, 0])
        Q_out[k], PSI[k], Ps[k] = quat, psi, kf.P
    if smooth:
        Q_out, PSI, Ps = rts_eskf(Q_out, PSI, Ps, step, resets)
    return Q_out, PSI, Ps, Innovations(nis, logdet, 3), resets


def filter_fast(t, quat_meas, q, r, discretisation="thesis", smooth=False, reset_deg=RESET_DEG, gyro=None,
                r_gyro=None):
    """Compiled equivalent of :func:`filter_reference`.

    Returns quaternions, world rates ψ, variances (N, 12), the ω and α
    covariance blocks (N, 2, 3, 3), :class:`Innovations` and the restart flags.
    """
    from . import fast
    from ..linalg_compiled import kernel_array

    valid = np.all(np.isfinite(quat_meas), axis=1)
    quat0, psi0, P0 = initial(quat_meas[int(np.argmax(valid))], r)
    qd = np.broadcast_to(np.asarray(q, dtype=float), (3,)).copy()
    exact = discretisation == "exact"
    reset = -1.0 if reset_deg is None else float(np.radians(reset_deg))
    zg = np.zeros((len(t), 3)) if gyro is None else kernel_array(gyro)
    gvalid = np.zeros(len(t), dtype=bool) if gyro is None else np.all(np.isfinite(zg), axis=1)
    QT, PSI, Ps, V, Bl, nis, logdet, resets = fast.eskf_forward(t, kernel_array(quat_meas), valid, qd, float(r), exact,
                                                                quat0, psi0, P0, smooth, reset, zg, gvalid,
                                                                float(r_gyro or 1.0))
    if smooth:
        fast.eskf_smooth(t, QT, PSI, Ps, qd, exact, equilibration(Ps), resets)
        V, Bl = covariance_summary(Ps)
    return QT, PSI, V, Bl, Innovations(nis[:, None], logdet[:, None], 3), resets


def covariance_summary(Ps):
    """Variances (N, 12) and the ω, α blocks (N, 2, 3, 3) of covariances (N, 12, 12)."""
    return np.einsum("nii->ni", Ps).copy(), np.stack([Ps[:, 3:6, 3:6], Ps[:, 6:9, 6:9]], axis=1)


def body_rates(quat, psi, blocks):
    """Body-frame ω, α (N, 3 each) and their standard deviations from world rates and covariance blocks."""
    R = quat_to_rot(quat)
    w = np.einsum("nji,nj->ni", R, psi[:, 0:3])
    al = np.einsum("nji,nj->ni", R, psi[:, 3:6])
    # diag(Rᵀ B R) = Σ_j R_ji (B R)_ji: a batched product, not a three-operand einsum (ten times slower)
    sd = [np.sqrt(np.sum(R * np.matmul(blocks[:, b], R), axis=1)) for b in (0, 1)]
    return w, al, sd[0], sd[1]


def rts_eskf(quat, psi, Ps, step, resets):
    """RTS pass of the attitude ESKF (numpy reference): the linear recursion on the error state, with the
    mean difference ``x_s,k+1 ⊖ x⁻_k+1`` taken on SO(3) (``log(q⁻⁻¹ ⊗ q_s)``) and the correction
    injected with ``q ⊗ exp(δθ)``, as in the filter's update (equilibrated as
    :mod:`qr.estimation.smoother` explains).

    ``quat`` (N, 4), ``psi`` (N, 9) and ``Ps`` (N, 12, 12) are the filter's
    posteriors; ``step(k)`` returns ``(Φ, Q, q⁻, ψ⁻)`` of the prediction from
    sample ``k`` to ``k + 1``; where the filter restarted (``resets[k+1]``)
    the chain is cut.  Returns smoothed ``quat, psi, Ps``.
    """
    N = len(quat)
    d = equilibration(Ps)
    dd = d[:, None] * d[None, :]
    quat, psi, Ps = quat.copy(), psi.copy(), Ps.copy()
    for k in range(N - 2, -1, -1):
        if resets[k + 1]:
            continue
        Phi, Q, q_pred, psi_pred = step(k)
        Pk = Ps[k] * dd
        Phi_s = d[:, None] * Phi / d[None, :]
        pP = Phi_s @ Pk @ Phi_s.T + Q * dd
        C = Pk @ Phi_s.T @ np.linalg.inv(pP)
        delta = boxminus(quat[k + 1], psi[k + 1], q_pred, psi_pred) * d
        quat[k], psi[k] = inject(quat[k], psi[k], (C @ delta) / d)
        Ps[k] = (Pk + C @ (Ps[k + 1] * dd - pP) @ C.T) / dd
    return quat, psi, Ps
