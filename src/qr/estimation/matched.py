"""Rotor signals smoothed like the motion estimates, so residual labels compare like with like.

A linear smoother estimates a derivative as the smoothed true one (``â = H_p a``), so the rotor terms pass
through the same smoothers (``T = B₀ H_p(u²)``, ``Γ = B₁₋₃ H_θ(u²)``); else the two smoothers' difference shows
up as spurious effects.  docs/diagnose.md "How it decides".
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from . import position_kf
from .settings import resolve
from .smoother import equilibration
from .tuning import ORDER
from ..flight import ROTORS
from ..parallel import thread_map
from ..states import U2_FORCE, U2_FORCE_RATE, U2_TORQUE, U2_TORQUE_RATE


def _smooth(t, y, q, r, discretisation):
    """Zero-lag estimates and rates of each column of ``y`` through the position-type chain smoother
    (order 4, the same as the position filter and the attitude ESKF's per-axis chain).  Columns with
    the same dropouts share one covariance recursion (one compiled pass for all four rotors)."""
    from . import fast
    from ..linalg_compiled import kernel_array

    out, rate = np.full_like(y, np.nan), np.full_like(y, np.nan)
    valid = np.isfinite(y)
    groups: dict[bytes, list[int]] = {}
    for i in range(y.shape[1]):
        groups.setdefault(valid[:, i].tobytes(), []).append(i)
    P0 = position_kf.initial(np.zeros(3), r)[1][::3, ::3].copy()
    for cols in groups.values():
        ok = valid[:, cols[0]]
        if not ok.any():
            continue
        x0 = np.zeros((len(cols), ORDER["position"]))
        x0[:, 0] = y[int(np.argmax(ok)), cols]
        X, _, Ps, _, _ = fast.chain_forward(t, kernel_array(y[:, cols]), ok, float(q), float(r),
                                            discretisation == "exact", x0, P0, True)
        fast.chain_smooth(t, X, Ps, float(q), discretisation == "exact", equilibration(Ps))
        out[:, cols], rate[:, cols] = X[:, :, 0], X[:, :, 1]
    return out, rate


def add_matched_rotor_signals(states: pd.DataFrame, flight: pd.DataFrame, filter_cfg: dict) -> pd.DataFrame:
    """``states`` plus ``u2f*``, ``u2fd*``, ``u2t*``, ``u2td*`` from the flight's raw rotor speeds."""
    cfg = resolve(filter_cfg)
    t = flight["t"].to_numpy()
    u2 = flight[ROTORS].to_numpy() ** 2
    q_att = float(np.exp(np.mean(np.log(np.atleast_1d(cfg["attitude"]["q"])))))
    out = states.copy()
    assert ORDER["position"] == ORDER["attitude"] == 4
    scale = float(np.nanvar(u2)) or 1.0  # only q/r sets the smoother's response; scale both to the signal's units
    pairs = ((U2_FORCE, U2_FORCE_RATE, cfg["position"]["q"], cfg["position"]["r"]),
             (U2_TORQUE, U2_TORQUE_RATE, q_att, cfg["attitude"]["r"]))
    smoothed = thread_map(lambda p: _smooth(t, u2, float(p[2]) / float(p[3]) * scale, scale, cfg["discretisation"]),
                          pairs)
    for (cols, rates, _, _), (x, xd) in zip(pairs, smoothed):
        out[cols] = x
        out[rates] = xd
    return out
