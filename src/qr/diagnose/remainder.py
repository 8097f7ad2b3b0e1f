"""What the named effects leave: structure beyond the catalog (:func:`remainder`: a non-leaking learned model
judged on the held-out part) and the learned torque remainder (:func:`fit_torque_remainder`: a linear map
written into the extended vehicle as a hybrid, not a cause); both on the cross-fitted labels (no shared
noise).  docs/diagnose.md "How it decides", step 10.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .. import torque_remainder as trm
from ..parallel import thread_map
from .core import extended_prediction, rms
from .fit import Fit
from .labels import weights
from .settings import DiagnoseConfig


def _left(f: Fit, vehicle, rows: np.ndarray) -> np.ndarray:
    """The residual the named effects leave on ``rows`` of the cross-fitted labels."""
    prep = f.labels.cross
    return prep.y[rows] - extended_prediction(prep, vehicle, f.named, f.theta, rows, f.force_only)


@dataclass(frozen=True)
class Beyond:
    """Structure beyond the catalog: how much of the held-out residual the named effects leave a linear model
    of the states removes (all input groups, and each alone), and the group it is most correlated with."""

    evaluated: bool
    statement: str
    structure_remains: bool = False
    held_out_gain: float | None = None
    by_input_group: Mapping[str, float] | None = None  # input group (diagnose.remainder_inputs) -> gain alone
    correlated_with: str | None = None  # where structure remains

    def record(self) -> dict:
        """``diagnosis.json``'s ``remainder``."""
        if not self.evaluated:
            return {"evaluated": False, "statement": self.statement}
        return {"evaluated": True, "structure_remains": self.structure_remains, "held_out_gain": self.held_out_gain,
                "by_input_group": dict(self.by_input_group), "correlated_with": self.correlated_with,
                "statement": self.statement}


def remainder(f: Fit, vehicle, cfg: DiagnoseConfig) -> Beyond:
    try:
        from ..datasets import features
        from ..models import fit
    except ImportError:
        return Beyond(False, "Not evaluated: the learning stage (qr.models) is not installed.")
    prep = f.labels.cross
    tr, te = np.flatnonzero(prep.train), np.flatnonzero(prep.test)
    s_tr, s_te = prep.s.take(tr), prep.s.take(te)
    r_tr, r_te = _left(f, vehicle, tr), _left(f, vehicle, te)
    w_te = weights(prep.sd)[te]
    l0 = float(np.nanmean(w_te * r_te**2))

    def gain(inputs):
        X_tr, X_te = features(s_tr, inputs), features(s_te, inputs)
        ok = np.isfinite(X_tr).all(1) & np.isfinite(r_tr).all(1)
        model = fit("linear", X_tr[ok], r_tr[ok], {})
        return 1 - float(np.nanmean(w_te * (r_te - model.predict(X_te)) ** 2)) / l0

    groups = list(cfg.remainder_inputs)
    g_all, *alone = thread_map(gain, [groups] + [[g] for g in groups])  # independent fits, side by side
    per_group = dict(zip(groups, alone))
    top = max(per_group, key=per_group.get)
    remains = g_all > cfg.remainder_min_gain
    statement = (f"Unexplained residual: a linear model on {', '.join(cfg.remainder_inputs)} removes "
                 f"{100 * g_all:.1f} % of the remaining held-out residual variance; it is most correlated with "
                 f"`{top}` ({100 * per_group[top]:.1f} % alone)." if remains else
                 f"No structure left: a linear model on {', '.join(cfg.remainder_inputs)} removes only "
                 f"{100 * g_all:.1f} % of the remaining held-out residual variance (threshold "
                 f"{100 * cfg.remainder_min_gain:.0f} %).")
    return Beyond(True, statement, bool(remains), round(g_all, 4), {k: round(v, 4) for k, v in per_group.items()},
                  top if remains else None)


@dataclass(frozen=True)
class TorqueRemainder:
    """The learned torque remainder fitted on the training part, and its held-out torque RMSE (x, y, z)
    beside the extended model's."""

    weights: np.ndarray  # (3, N_FEATURES): torque = features @ weights.T
    ridge: float
    extended_torque_rmse: list[float]
    hybrid_torque_rmse: list[float]

    def in_vehicle(self, vehicle, note: str) -> dict:
        """The ``torque_remainder`` block of a vehicle file: these weights added to the vehicle's own."""
        own = trm.weights(vehicle)
        return trm.block(self.weights + (own if own is not None else 0.0), note)


def fit_torque_remainder(f: Fit, vehicle, ridge: float) -> TorqueRemainder:
    """The learned torque remainder of what ``f`` leaves (see the module doc)."""
    prep = f.labels.cross
    tr = np.flatnonzero(prep.train)
    s_tr = prep.s.take(tr)
    W = trm.fit(trm.features(s_tr.v_b, s_tr.omega, s_tr.u, vehicle.hover_speed), _left(f, vehicle, tr)[:, 3:6], ridge)
    te = np.flatnonzero(prep.test)  # cross-fitted too: a label's own rotor noise is not in its features
    s_te = prep.s.take(te)
    r_te = _left(f, vehicle, te)
    hybrid = r_te[:, 3:6] - trm.features(s_te.v_b, s_te.omega, s_te.u, vehicle.hover_speed) @ W.T
    return TorqueRemainder(W, ridge, rms(r_te[:, 3:6]).tolist(), rms(hybrid).tolist())
