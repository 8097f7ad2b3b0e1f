"""Rotor signals smoothed like the motion estimates, so residual labels compare like with like.

The force label is ``m â - m Rᵀg - T`` with ``â`` from the position smoother and
the torque label ``J α̂ - (Jω)×ω - Γ`` with ``α̂`` from the attitude smoother.
For a linear smoother the estimate of a derivative is the smoothed true
derivative (``â = H_p a``, ``α̂ ≈ H_θ α``), so the rotor terms must pass through
the same ``H``: ``T = B₀ H_p(u²)``, ``Γ = B₁₋₃ H_θ(u²)`` (``T`` and ``Γ`` are
linear in the squared speeds).  Otherwise the difference between two smoothers
(and rotor noise shared by label and regressor) shows up as spurious effects.
The squared raw speeds go through the position and attitude chain smoothers
(same order and bandwidth); the first-derivative outputs give the rates the
``actuator_delay`` term needs.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..estimation import position_kf
from ..estimation.settings import resolve
from ..estimation.tuning import ORDER
from ..flight import ROTORS
from ..states import U2_FORCE, U2_FORCE_RATE, U2_TORQUE, U2_TORQUE_RATE


def _smooth(t, y, q, r, discretisation):
    """Zero-lag estimates and rates of each column of ``y`` through the position-type chain smoother
    (order 4, the same as the position filter and the attitude ESKF's per-axis chain)."""
    out, rate = np.empty_like(y), np.empty_like(y)
    groups = [(0, 1, 2), (3, 3, 3)]  # the smoother takes three channels at a time
    for g in groups:
        X, _, _ = position_kf.filter_fast(t, y[:, list(g)], q, r, discretisation, smooth=True)
        for j, col in enumerate(g):
            out[:, col], rate[:, col] = X[:, j], X[:, 3 + j]
    return out, rate


def add_matched_rotor_signals(states: pd.DataFrame, flight: pd.DataFrame, filter_cfg: dict) -> pd.DataFrame:
    """``states`` plus ``u2f*``, ``u2fd*``, ``u2t*``, ``u2td*`` from the flight's raw rotor speeds."""
    cfg = resolve(filter_cfg)
    t = flight["t"].to_numpy()
    u2 = flight[ROTORS].to_numpy() ** 2
    q_att = float(np.exp(np.mean(np.log(np.atleast_1d(cfg["attitude"]["q"])))))
    out = states.copy()
    assert ORDER["position"] == ORDER["attitude"] == 4
    for cols, rates, q, r in ((U2_FORCE, U2_FORCE_RATE, cfg["position"]["q"], cfg["position"]["r"]),
                              (U2_TORQUE, U2_TORQUE_RATE, q_att, cfg["attitude"]["r"])):
        # only q/r sets the smoother's response; scale both to the signal's units
        scale = float(np.nanvar(u2)) or 1.0
        x, xd = _smooth(t, u2, float(q) / float(r) * scale, scale, cfg["discretisation"])
        out[cols] = x
        out[rates] = xd
    return out
