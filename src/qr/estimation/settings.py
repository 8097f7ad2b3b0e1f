"""Filter settings: the ``filter`` config group as a validated dict.

``DEFAULTS`` mirrors ``conf/filter/thesis.yaml`` (a test keeps them equal), so
library callers need no Hydra.  Any mistake is one :class:`QrInputError` line.
"""

from __future__ import annotations

import copy
import math

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
                 "reset_deg": attitude_eskf.RESET_DEG},
    "motor": {"q": motor_kf.THESIS_Q, "r": motor_kf.THESIS_R},
    "tune": {"enabled": False, "min_corner_hz": 0.05, "grid": 13, "rounds": 2, "max_samples": 60000},
    "nis": {"confidence": 0.95, "burn_in_s": 1.0},
    "flight": None,  # input, output and vehicle of `python -m qr.filter`; ignored by estimate()
    "out": None,
    "vehicle": None,
}
FIX = "see conf/filter/thesis.yaml for the keys and their meaning"


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
    for key in ("smoother", "tune.enabled"):
        v = s[key] if "." not in key else s["tune"]["enabled"]
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
    conf = s["nis"]["confidence"]
    if not 0 < float(conf) < 1:
        raise _bad(f"'nis.confidence' must be in (0, 1), got {conf!r}")
    if float(s["nis"]["burn_in_s"]) < 0:
        raise _bad(f"'nis.burn_in_s' must be >= 0, got {s['nis']['burn_in_s']!r}")
    if s["tune"]["enabled"] and s["discretisation"] != "exact":
        raise _bad("tune.enabled needs discretisation: exact (q as a noise intensity, valid at any dt)",
                   "use filter=auto, or set filter.discretisation=exact")
    _positive(s["tune"]["min_corner_hz"], "tune.min_corner_hz")
    if int(s["tune"]["max_samples"]) < 100:
        raise _bad(f"'tune.max_samples' must be at least 100, got {s['tune']['max_samples']!r}")
    if int(s["tune"]["grid"]) < 3 or int(s["tune"]["rounds"]) < 1:
        raise _bad("tune.grid must be >= 3 and tune.rounds >= 1")
    return s
