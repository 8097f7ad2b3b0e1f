"""Filter settings: the ``filter`` config group, its defaults written once (:class:`FilterNode`, Hydra's
structured config for the group; ``conf/filter/thesis.yaml`` selects it, ``smoother.yaml`` and
``auto.yaml`` override some keys), and :func:`resolve`, which checks a group as a plain dict, so library
callers need no Hydra.  Any mistake is one :class:`QrInputError` line.
"""

from __future__ import annotations

import copy
import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any, Optional

from ..allowed import setting
from ..errors import QrInputError
from . import attitude_eskf, motor_kf, position_kf
from .chain import DISCRETISATIONS

FILTERS = ("position", "attitude", "motor")
IMPLEMENTATIONS = ("fast", "reference")
# The filter of the estimates a diagnosis reads, and of the start states qr evaluate rolls out from: the
# default of diagnose.filter and evaluate.filter, and the workflow's filter stage makes its cross-fit
# files with it (workflow/rules/filter.smk), so the diagnoses read them instead of filtering again.
# ``auto`` tunes each flight's noise values by the innovations' likelihood (.tuning).
DIAGNOSIS_FILTER = "auto"


# q and r: a number (or attitude q: one or three); Any, since qr's own check (resolve) says what is wrong
@dataclass
class PositionSettings:
    """KF on [p, v, a, j] (thesis eqs. 4.4-4.10)."""

    q: Any = position_kf.THESIS_Q  # eq. 4.6a: Q = 100 [[0, 0], [0, 0.1 I3]] on the jerk
    r: Any = position_kf.THESIS_R  # eq. 4.6b: R = 0.0002^2 I3 (m^2)


@dataclass
class AttitudeSettings:
    """ESKF on [q, w, alpha, alpha_dot] (eqs. 4.11-4.27), rates in the world frame."""

    # eq. 4.16a: Q = 500 diag(1, 0.1, 1) on alpha_ddot; Qd = G Q G^T dt^2 (4.20)
    q: Any = field(default_factory=lambda: attitude_eskf.THESIS_Q.tolist())
    r: Any = attitude_eskf.THESIS_R  # eq. 4.16b: R_nu = 0.001^2 I3 (rad^2)
    # not in the thesis: restart the ESKF at the next measurement when the innovation angle or the
    # predicted rotation between samples exceeds this (track lost: the log map aliases); null: never
    reset_deg: Any = attitude_eskf.RESET_DEG
    gyro: bool = False  # not in the thesis: fuse the log's gyro (gx, gy, gz) where it has one


@dataclass
class MotorSettings:
    """One KF per rotor on [u, u_dot, u_ddot] (eqs. 4.28-4.33)."""

    q: Any = motor_kf.THESIS_Q  # eq. 4.31a: Q = 10000 diag(0, 0, 0.1)
    r: Any = motor_kf.THESIS_R  # eq. 4.31b: R = 1 ((rotor speed unit)^2)


@dataclass
class TuneSettings:
    """Likelihood search of q and r per filter (filter=auto)."""

    enabled: bool = False
    min_corner_hz: float = setting(0.05, gt=0)  # lowest bandwidth searched (the highest is Nyquist)
    grid: int = setting(13, "integer", ge=3)  # log-spaced bandwidths tried before the Brent refinement
    rounds: int = setting(2, "integer", ge=1)
    # longer flights (segments) are tuned on their middle max_samples (the noise is stationary)
    max_samples: int = setting(60000, "integer", ge=100)


@dataclass
class NisSettings:
    confidence: float = setting(0.95, gt=0, lt=1)  # chi-square band of the NIS mean; outside: flagged
    burn_in_s: float = setting(1.0, ge=0)  # initial transient left out of NIS and likelihood


@dataclass
class FilterNode:
    """The ``filter`` group: the thesis's three filters (§4.2.1), matrices as printed, forward only."""

    name: str = "thesis"
    implementation: str = "fast"  # fast (compiled) | reference (filterpy; slow, same numbers to 1e-9)
    smoother: bool = False  # true: Rauch-Tung-Striebel backward pass (zero lag, smaller errors)
    # thesis: Q as printed, added once per sample | exact: q a white-noise intensity, Q(dt) integrated
    discretisation: str = "thesis"
    position: PositionSettings = field(default_factory=PositionSettings)
    attitude: AttitudeSettings = field(default_factory=AttitudeSettings)
    motor: MotorSettings = field(default_factory=MotorSettings)
    tune: TuneSettings = field(default_factory=TuneSettings)
    nis: NisSettings = field(default_factory=NisSettings)
    flight: Optional[str] = None  # qr filter only: the input flight (canonical CSV or Parquet)
    out: Optional[str] = None  # qr filter only: the state table (default <results>/filter/<name>.parquet)
    vehicle: Optional[str] = None  # qr filter only: vehicle name or YAML (default: the root `vehicle`)


DEFAULTS = asdict(FilterNode())
SOURCE = "src/qr/estimation/settings.py"
FIX = f"see {SOURCE} (FilterNode) for the keys and their meaning"
# the ranges declared on the fields above, by (group, key)
RANGES = {(g.name, f.name): f.metadata["allowed"] for g in fields(FilterNode) if g.name in ("tune", "nis")
          for f in fields(g.default_factory) if "allowed" in f.metadata}


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
        s[group][key] = rule.check(f"filter.{group}.{key}", s[group][key], DEFAULTS[group][key], SOURCE)
    if s["tune"]["enabled"] and s["discretisation"] != "exact":
        raise _bad("tune.enabled needs discretisation: exact (q as a noise intensity, valid at any dt)",
                   "use filter=auto, or set filter.discretisation=exact")
    return s
