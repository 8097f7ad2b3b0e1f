"""Disturbance-force models for the simulation study: ``model.predict(signals) -> (N, 3)``, the unmodelled
body-frame force ``f_a`` (eq. 4.34) the study injects into the plant and the compensated controller cancels.

Adapters: :class:`LinearForce` (``W x + b``, eq. 4.35; :func:`thesis_model8`, eq. 4.38), :class:`CatalogForce`
(catalog effects; :func:`extended_vehicle`), :class:`LearnedForce` (``qr.models.load``), and the fitted
stand-ins :func:`fit_linear` / :func:`fit_effects`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numba as nb
import numpy as np

from ..effects import Signals, get, total_term, validate_effect_list
from ..errors import QrInputError

# input groups of the learning stage (qr.datasets.GROUPS; a test keeps the two equal): name -> columns
GROUP_SIZES = {"v_b": 3, "a_b": 3, "p": 3, "p_z": 1, "q": 4, "omega": 3, "alpha": 3, "u": 4, "u2": 4}

# Thesis eq. 4.38: model 8 (inputs v_b, u; two linear hidden layers collapsed by eq. 4.36).
MODEL8_W = np.array([[-0.2053, 0.0017, 0.0156, -0.0242, 0.0473, 0.0474, -0.1034],
                     [-0.0992, -0.4139, -0.0479, -0.2134, 0.0402, -0.0952, 0.1189],
                     [-0.0387, 0.0313, 0.0203, -0.2092, -0.0329, -0.0251, -0.2713]])
MODEL8_B = np.array([0.4768, 0.2994, -0.3817])
# Eq. 4.38 cannot take u in rpm (Table 4.1's unit): at hover (5873 rpm) it would predict
# -3.2 kN along z.  The thesis's MATLAB network most likely worked on normalised inputs whose
# ranges are not given.  Reading u in units of 1e4 rpm puts the hover force at
# [0.46, 0.21, -0.70] N, the size of the thesis's residual (nominal RMSE 0.563 N).
MODEL8_U_SCALE = 1.0e4


@nb.njit(cache=True)
def _quaternions(R):
    n = R.shape[0]
    q = np.empty((n, 4))
    for i in range(n):
        r = R[i]
        tr = r[0, 0] + r[1, 1] + r[2, 2]
        if tr >= r[0, 0] and tr >= r[1, 1] and tr >= r[2, 2]:
            w = 0.5 * np.sqrt(1.0 + tr)
            q[i] = [w, (r[2, 1] - r[1, 2]) / (4 * w), (r[0, 2] - r[2, 0]) / (4 * w), (r[1, 0] - r[0, 1]) / (4 * w)]
        elif r[0, 0] >= r[1, 1] and r[0, 0] >= r[2, 2]:
            x = 0.5 * np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
            q[i] = [(r[2, 1] - r[1, 2]) / (4 * x), x, (r[0, 1] + r[1, 0]) / (4 * x), (r[0, 2] + r[2, 0]) / (4 * x)]
        elif r[1, 1] >= r[2, 2]:
            y = 0.5 * np.sqrt(1.0 - r[0, 0] + r[1, 1] - r[2, 2])
            q[i] = [(r[0, 2] - r[2, 0]) / (4 * y), (r[0, 1] + r[1, 0]) / (4 * y), y, (r[1, 2] + r[2, 1]) / (4 * y)]
        else:
            z = 0.5 * np.sqrt(1.0 - r[0, 0] - r[1, 1] + r[2, 2])
            q[i] = [(r[1, 0] - r[0, 1]) / (4 * z), (r[0, 2] + r[2, 0]) / (4 * z), (r[1, 2] + r[2, 1]) / (4 * z), z]
        if q[i, 0] < 0:
            q[i] = -q[i]
    return q


def quaternions(R: np.ndarray) -> np.ndarray:
    """Scalar-first quaternions with ``qw >= 0`` of rotations (N, 3, 3), as ``frames.rot_to_quat``.

    Shepperd's method in numba: scipy's conversion costs ~50 µs per call, too slow
    for a model evaluated at every step of the closed loop.
    """
    return _quaternions(np.ascontiguousarray(np.asarray(R, dtype=float).reshape(-1, 3, 3)))


def group_values(s: Signals, name: str, u_scale: float = 1.0) -> np.ndarray:
    if name == "q":
        return quaternions(s.R)
    if name == "u":
        return s.u / u_scale
    if name == "u2":
        return (s.u / u_scale) ** 2
    if name == "p_z":
        return s.p[:, 2:3]
    if name in GROUP_SIZES:
        return getattr(s, name)
    raise QrInputError("inputs", f"unknown input group {name!r}", f"use groups from {list(GROUP_SIZES)}")


def features(s: Signals, inputs, u_scale: float = 1.0) -> np.ndarray:
    """Input matrix ``(N, sum of group sizes)``: groups concatenated in the order given."""
    return np.hstack([group_values(s, g, u_scale) for g in inputs])


def _check_inputs(inputs, where):
    bad = [g for g in inputs if g not in GROUP_SIZES]
    if bad:
        raise QrInputError(where, f"unknown input group(s) {bad}", f"use groups from {list(GROUP_SIZES)}")


@dataclass
class LinearForce:
    """``f_a = W x + b`` with ``x`` the concatenated input groups (u divided by ``u_scale``)."""

    W: np.ndarray  # (3, n_inputs)
    b: np.ndarray  # (3,)
    inputs: tuple[str, ...]
    name: str = "linear"
    u_scale: float = 1.0

    def __post_init__(self):
        self.W = np.atleast_2d(np.asarray(self.W, dtype=float))
        self.b = np.asarray(self.b, dtype=float).reshape(3)
        self.inputs = tuple(self.inputs)
        _check_inputs(self.inputs, f"{self.name}.inputs")
        n = sum(GROUP_SIZES[g] for g in self.inputs)
        if self.W.shape != (3, n):
            raise QrInputError(self.name, f"W is {self.W.shape}, inputs {list(self.inputs)} need (3, {n})",
                               "give one W row per force axis and one column per input")

    def predict(self, s: Signals) -> np.ndarray:
        return features(s, self.inputs, self.u_scale) @ self.W.T + self.b

    def block(self, group: str) -> np.ndarray:
        """Columns of ``W`` acting on ``group`` (3, size), zeros if the model does not use it."""
        if group not in self.inputs:
            return np.zeros((3, GROUP_SIZES[group]))
        i = 0
        for g in self.inputs:
            if g == group:
                scale = self.u_scale if g == "u" else self.u_scale**2 if g == "u2" else 1.0
                return self.W[:, i:i + GROUP_SIZES[g]] / scale
            i += GROUP_SIZES[g]
        raise AssertionError  # pragma: no cover

    def collapse(self):
        return self.W, self.b


def thesis_model8(u_scale: float = MODEL8_U_SCALE) -> LinearForce:
    """The thesis's model 8 (eq. 4.38a/b) on ``[v_b; u]``."""
    return LinearForce(MODEL8_W, MODEL8_B, ("v_b", "u"), "thesis_model8", float(u_scale))


@dataclass
class CatalogForce:
    """The force part of catalog effects (``qr.effects``) for a vehicle."""

    effects: list[dict]
    vehicle: object
    name: str = "catalog"
    inputs: tuple[str, ...] = ("catalog",)  # physical terms (a mass error uses a_b, as physics does)

    def __post_init__(self):
        self.effects = validate_effect_list(self.effects, self.name)

    def predict(self, s: Signals) -> np.ndarray:
        return total_term(self.effects, s, self.vehicle)[:, :3]


def extended_vehicle(path):
    """``(nominal vehicle, effects)`` of an extended vehicle YAML (``qr diagnose``'s output)."""
    from ..vehicle import load_vehicle

    v = load_vehicle(path)
    if not v.effects:
        raise QrInputError(path, "the vehicle file names no effects, so it is not an extended vehicle",
                           "give the extended_vehicle.yaml that qr diagnose writes (a vehicle plus 'effects:')")
    effects = validate_effect_list(v.effects, path)
    return v.with_changes(effects=[]), effects


class LearnedForce:
    """A force model saved by the learning stage, loaded with ``qr.models.load``."""

    def __init__(self, path, name: str | None = None):
        try:
            from .. import datasets, models  # lazily: the learning stage is optional here
        except ImportError as e:
            raise QrInputError(path, f"cannot load a learned model: {e}",
                               "install the learning stage (qr.models, qr.datasets) or drop this source") from None
        if not Path(path).exists():
            raise QrInputError(path, "learned model not found", "give the directory the training stage wrote")
        self.model = models.load(path)
        self._features = datasets.features
        self.inputs = tuple(self.model.inputs)
        self.name = name or f"learned:{Path(path).name}"
        if getattr(self.model, "target", "f_a") != "f_a":
            raise QrInputError(path, f"the model predicts {self.model.target!r}, not the force f_a",
                               "give a force model (target f_a)")

    def predict(self, s: Signals) -> np.ndarray:
        return np.asarray(self.model.predict(self._features(s, list(self.inputs))), dtype=float).reshape(-1, 3)

    def as_linear(self) -> LinearForce:
        """The collapsed affine map (linear networks only), for the stability analysis."""
        W, b = self.model.collapse()
        return LinearForce(W, b, self.inputs, self.name)


# ---- stand-ins for learning / identification on a simulated flight -------------------------

def fit_linear(s: Signals, f_a: np.ndarray, inputs, name: str = "linear_fit", u_scale: float = 1.0) -> LinearForce:
    """Least-squares ``W, b`` on the input groups (what a linear network converges to)."""
    X = features(s, inputs, u_scale)
    mu, sd = X.mean(0), X.std(0)
    sd[sd == 0] = 1.0
    A = np.hstack([(X - mu) / sd, np.ones((len(X), 1))])
    coef, *_ = np.linalg.lstsq(A, f_a, rcond=None)
    W = (coef[:-1] / sd[:, None]).T
    b = coef[-1] - W @ mu
    return LinearForce(W, b, tuple(inputs), name, u_scale)


def fit_effects(s: Signals, f_a: np.ndarray, names, vehicle, name: str = "effects_fit") -> CatalogForce:
    """Parameters of the named catalog effects by least squares on the force rows (a known-structure fit)."""
    designs, spans = [], []
    for n in names:
        eff = get(n, name)
        designs.append(eff.design(s, vehicle)[:, :3, :])
        spans.append(eff)
    D = np.concatenate(designs, axis=2)  # (N, 3, k)
    theta, *_ = np.linalg.lstsq(D.reshape(-1, D.shape[2]), f_a.reshape(-1), rcond=None)
    effects, i = [], 0
    for eff in spans:
        k = len(eff.params)
        effects.append({"name": eff.name, "parameters": {p: float(n + t) for p, n, t in
                                                         zip(eff.params, eff.neutral, theta[i:i + k])}})
        i += k
    return CatalogForce(effects, vehicle, name)

