"""The settings of ``qr diagnose``, each with its default and allowed values: the one place they are
written.  :class:`DiagnoseNode` is the config group ``diagnose``'s structured config (registered in
Hydra's ConfigStore by :func:`qr.config.register_schemas`; ``conf/diagnose/default.yaml`` selects it).

Every field declares its type and range once, beside it (:func:`qr.allowed.setting`), and
one function (:func:`qr.allowed.check_fields`) holds the values to them, so a wrong override
(``diagnose.train_fraction=1.5``, ``diagnose.horizon_s=abc``) is one line naming the
key, the value and the allowed range, before any work is done.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import ClassVar

from ..allowed import check_fields, check_known, setting, show
from ..effects import CATALOG, MAX_DELAY_S
from ..errors import QrInputError
from ..estimation.settings import DIAGNOSIS_FILTER
from ..identification.selection import SelectionConfig  # noqa: F401  (a group of these settings)

DEFAULTS_FILE = "src/qr/diagnose/settings.py"
REFINE_MODES = ("none", "rollout")  # diagnose.refine (qr.diagnose.refine)
REFINE_BEYOND = ("auto", "hold", "bound")  # diagnose.refine_beyond


def _catalog() -> list[str]:
    return list(CATALOG)


def _checks() -> list[str]:
    from ..conventions import CHECKS

    return list(CHECKS)


def _leaking_groups() -> dict[str, str]:
    from ..datasets import LEAKS

    return {g: f"the residual {target} is computed from it (it would explain it trivially)"
            for target, groups in LEAKS.items() for g in groups}


def _remainder_groups() -> list[str]:
    from ..datasets import GROUPS

    return [g for g in GROUPS if g not in _leaking_groups()]


@dataclass
class DiagnoseConfig:
    KEY: ClassVar[str] = "diagnose"
    horizon_s: float = setting(1.0, gt=0)  # the open-loop replay restarts every horizon_s
    train_fraction: float = setting(0.7, gt=0, lt=1)  # the first 70 % of each flight trains, the rest is held out
    gap_s: float = setting(1.0, ge=0)  # ... with this gap between them (filter smoothing correlates neighbours)
    block_s: float = setting(2.0, gt=0)  # blocks for cross-validation and the block bootstrap
    trim_s: float = setting(0.5, ge=0)  # filter start-up and end dropped from each flight (segment)
    # null: the whole catalog; or a list of effect names
    candidates: list[str] | None = setting(None, "names", names=_catalog, null="the whole catalog", nonempty=True)
    # effects never to name (e.g. one fixed by an earlier diagnosis)
    exclude: list[str] = setting(kind="names", names=_catalog, default_factory=list)
    selection: SelectionConfig = field(default_factory=SelectionConfig)  # qr.identification.selection
    # the check for structure beyond the catalog: a linear model on these input groups of the remainder,
    # reported when it removes at least remainder_min_gain of the held-out residual variance
    remainder_inputs: list[str] = setting(kind="names", names=_remainder_groups, reasons=_leaking_groups,
                                          nonempty=True, default_factory=lambda: ["v_b", "u", "q", "omega", "p"])
    remainder_min_gain: float = setting(0.05, ge=0, le=1)
    delay_max_s: float = setting(0.1, gt=0, le=MAX_DELAY_S)  # the actuator delay searched up to this
    # > 0: fit a learned torque remainder (qr.torque_remainder) with this ridge, written into the
    # extended vehicle and rolled out as the "hybrid"; 0: none
    torque_remainder_ridge: float = setting(0.0, ge=0)
    # the slow torque balance (qr.diagnose.slow_torque): inertia judged on the residual summed over this
    # many samples (0: off), named per axis when it explains at least slow_torque_min_gain of that sum
    slow_torque_horizon: int = setting(50, "integer", ge=0)
    slow_torque_min_gain: float = setting(0.05, ge=0, le=1)
    # convention checks (qr.conventions) a user who knows the log better turns off, e.g. [rotor_layout]
    skip_checks: list[str] = setting(kind="names", names=_checks, default_factory=list)
    # rollout: refine the named effects' parameters and the vehicle's J, C_T, C_Q and a delay by the
    # evaluate protocol's multi-step error on the training part (qr.diagnose.refine); none: off
    refine: str = setting("none", "one", names=lambda: list(REFINE_MODES))
    refine_stride: int = setting(5, "integer", ge=1)  # every stride-th training start is a window
    refine_iterations: int = setting(30, "integer", ge=1, le=1000)  # Levenberg-Marquardt, at most
    refine_delay: bool = setting(True, "boolean")  # a pure delay among the vehicle's coefficients refined
    # per-rotor C_T and C_Q gains, the CG, the rotors' inertia and the flapping pitch/roll ratio refined too
    refine_rotors: bool = setting(True, "boolean")
    # a parameter the rollout wants beyond its physical range: fitted again within its range and the force and
    # torque balance (bound), written at its one-step value (hold), or whichever of the two rolls out better on
    # the held-out windows (auto); reported either way
    refine_beyond: str = setting("bound", "one", names=lambda: list(REFINE_BEYOND))

    def __post_init__(self):
        check_fields(self, lambda name: f"{self.KEY}.{name}", DEFAULTS_FILE)
        if not isinstance(self.selection, SelectionConfig):
            raise QrInputError("diagnose.selection", f"{show(self.selection)} is not a mapping of settings",
                               "override its keys one by one, e.g. diagnose.selection.folds=5")
        left = [e for e in (self.candidates or list(CATALOG)) if e not in self.exclude]
        if not left:
            raise QrInputError("diagnose.exclude", f"{show(self.exclude)} leaves no candidate effect to test",
                               "exclude fewer effects (or widen diagnose.candidates)")

    @classmethod
    def from_dict(cls, d: dict) -> "DiagnoseConfig":
        d = dict(d or {})
        sel = d.pop("selection", None) or {}
        if not isinstance(sel, dict):
            raise QrInputError("diagnose.selection", f"{show(sel)} is not a mapping of settings",
                               "override its keys one by one, e.g. diagnose.selection.folds=5")
        check_known(SelectionConfig.KEY, sel, SelectionConfig, DEFAULTS_FILE)
        names = {f.name for f in fields(cls)}
        known = {k: v for k, v in d.items() if k in names}  # (filter, track: read elsewhere)
        return cls(selection=SelectionConfig(**sel), **known)


@dataclass
class DiagnoseNode(DiagnoseConfig):
    """The config group ``diagnose``: the settings, and the keys read before them."""

    filter: str = DIAGNOSIS_FILTER  # the filter config (conf/filter/) the flights are estimated with
    track: bool = False  # an MLflow run (the workflow turns it on; the CLI writes nothing outside OUTDIR)

