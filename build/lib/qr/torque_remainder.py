"""A learned torque remainder: what the named physical terms leave of the torque, as a linear map.

``τ_rem = W φ`` with ``φ = [v_b (3), ω (3), (u_i / u_hover)² − 1 (4), 1]`` (body velocity, body rate,
rotor loads; never ``a_b`` or ``α``, from which the label is computed: non-leaking), ``W`` (3, 11) in
N m per feature unit.  Fitted by ridge least squares on the training part of a diagnosis (after the
named effects), stored in the vehicle file under ``torque_remainder`` and applied by the one plant
(``qr.sim.plant``) wherever the vehicle flies: ``qr evaluate``, the replay, ``qr synth``, the study.
It is reported apart from the physical effects: a hybrid, not a cause.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import QrInputError

N_FEATURES = 11
FEATURES = "v_b (3), omega (3), (u_i/u_hover)^2 - 1 (4), 1"


def features(v_b: np.ndarray, omega: np.ndarray, u: np.ndarray, hover_speed: float) -> np.ndarray:
    return np.column_stack([v_b, omega, (u / hover_speed) ** 2 - 1, np.ones(len(v_b))])


def weights(vehicle) -> np.ndarray | None:
    """The vehicle's remainder ``W`` (3, 11), or None."""
    block = vehicle.raw.get("torque_remainder")
    return None if not block else np.asarray(block["weights"], float)


def torque(vehicle, v_b, omega, u) -> np.ndarray:
    """``τ_rem`` (N, 3) of the vehicle's remainder (zeros without one)."""
    W = weights(vehicle)
    if W is None:
        return np.zeros((len(v_b), 3))
    return features(v_b, omega, u, vehicle.hover_speed) @ W.T


def fit(X: np.ndarray, Y: np.ndarray, ridge: float) -> np.ndarray:
    """Ridge least squares on standardised features (the constant's column left unpenalised in scale)."""
    ok = np.isfinite(X).all(axis=1) & np.isfinite(Y).all(axis=1)
    X, Y = X[ok], Y[ok]
    sc = np.sqrt((X**2).mean(axis=0))
    sc[sc == 0] = 1.0
    Xn = X / sc
    A = Xn.T @ Xn + ridge * len(X) * np.eye(X.shape[1])
    return (np.linalg.solve(A, Xn.T @ Y) / sc[:, None]).T


def block(W: np.ndarray, note: str) -> dict:
    return {"features": FEATURES, "weights": [[float(f"{x:.6g}") for x in row] for row in W], "note": note}


def validate(raw, path) -> dict:
    fix = f"give torque_remainder as {{weights: 3 rows of {N_FEATURES} numbers}} (as qr diagnose writes it)"
    if not isinstance(raw, dict) or "weights" not in raw:
        raise QrInputError(path, "vehicle key 'torque_remainder' is not a mapping with 'weights'", fix)
    W = raw["weights"]
    if (not isinstance(W, list) or len(W) != 3
            or any(not isinstance(r, list) or len(r) != N_FEATURES for r in W)
            or any(isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x)
                   for r in W for x in r)):
        raise QrInputError(path, "vehicle key 'torque_remainder.weights' is not 3 rows of "
                                 f"{N_FEATURES} finite numbers", fix)
    return raw
