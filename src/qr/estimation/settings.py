"""Filter settings: the ``filter`` config group as a validated dict.

``DEFAULTS`` mirrors ``conf/filter/thesis.yaml`` (a test keeps them equal), so
library callers need no Hydra.  Any mistake is one :class:`QrInputError` line.
"""

from __future__ import annotations

import copy
import math

from ..allowed import allowed
from ..errors import QrInputError
from . import attitude_eskf, motor_kf, position_kf
from .chain import DISCRETISATIONS

FILTERS = ("position", "attitude", "motor")
IMPLEMENTATIONS = ("fast", "reference")

DEFAULTS = {
    "name": "thesis",
    "implementation": "fast",
    "smoother": False,
    "discretisation": "thesis",
    "position": {"q": position_kf.THESIS_Q, "r": position_kf.THESIS_R},
    "attitude": {"q": attitude_eskf.THESIS_Q.tolist(), "r": attitude_eskf.THESIS_R,
                 "reset_deg": attitude_eskf.RESET_DEG, "gyro": False},
    "motor": {"q": motor_kf.THESIS_Q, "r": motor_kf.THESIS_R},
    "tune": {"enabled": False, "min_corner_hz": 0.05, "grid": 13, "rounds": 2, "max_samples": 60000},
    "nis": {"confidence": 0.95, "burn_in_s": 1.0},
    "flight": None,  # input, output and vehicle of `qr filter`; ignored by estimate()
    "out": None,
    "vehicle": None,
}
FIX = "see conf/filter/thesis.yaml for the keys and their meaning"
RANGES = {
    ("nis", "confidence"): allowed(gt=0, lt=1),
    ("nis", "burn_in_s"): allowed(ge=0),
    ("tune", "min_corner_hz"): allowed(gt=0),
    ("tune", "max_samples"): allowed("integer", ge=100),
    ("tune", "grid"): allowed("integer", ge=3),
    ("tune", "rounds"): allowed("integer", ge=1),
}


def _bad(problem: str, fix: str = FIX) -> QrInputError:
    return QrInputError("filter config", problem, fix)


def _merge(base: dict, over: dict, path: str) -> dict:
    out = copy.deepcopy(base)
    for k, v in (over or {}).items():
        if k not in base:
            raise _bad(f"unknown key '{path}{k}' (known: {', '.join(base)})")
        out[k] = _merge(base[k], v, f"{path}{k}.") if isinstance(base[k], dict) else v
    return out


def _positive(x, key: str, n: int = 1):
    vals = x if isinstance(x, (list, tuple)) else [x]
    try:
        vals = [float(v) for v in vals]
    except (TypeError, ValueError):
        raise _bad(f"'{key}' must be a number, got {x!r}") from None
    if len(vals) not in (1, n) or not all(math.isfinite(v) and v > 0 for v in vals):
        raise _bad(f"'{key}' must be {'a positive number' if n == 1 else f'a positive number or {n} of them'}, "
                   f"got {x!r}")
    return vals[0] if len(vals) == 1 else vals


def resolve(cfg: dict | None) -> dict:
    """Defaults merged with ``cfg`` (a ``filter`` group as a plain dict), checked."""
    s = _merge(DEFAULTS, dict(cfg or {}), "")
    for key in ("smoother", "tune.enabled", "attitude.gyro"):
        v = s[key] if "." not in key else s[key.split(".")[0]][key.split(".")[1]]
        if not isinstance(v, bool):
            raise _bad(f"'{key}' must be true or false, got {v!r}")
    if s["implementation"] not in IMPLEMENTATIONS:
        raise _bad(f"implementation '{s['implementation']}' is not one of {IMPLEMENTATIONS}")
    if s["discretisation"] not in DISCRETISATIONS:
        raise _bad(f"discretisation '{s['discretisation']}' is not one of {DISCRETISATIONS}")
    for f in FILTERS:
        s[f]["q"] = _positive(s[f]["q"], f"{f}.q", 3 if f == "attitude" else 1)
        s[f]["r"] = _positive(s[f]["r"], f"{f}.r")
    if s["attitude"]["reset_deg"] is not None:
        s["attitude"]["reset_deg"] = _positive(s["attitude"]["reset_deg"], "attitude.reset_deg")
    for (group, key), rule in RANGES.items():
        s[group][key] = rule.check(f"filter.{group}.{key}", s[group][key], DEFAULTS[group][key],
                                   "conf/filter/thesis.yaml")
    if s["tune"]["enabled"] and s["discretisation"] != "exact":
        raise _bad("tune.enabled needs discretisation: exact (q as a noise intensity, valid at any dt)",
                   "use filter=auto, or set filter.discretisation=exact")
    return s
