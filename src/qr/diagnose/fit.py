"""The fit: which effects the training part names, their parameters and standard errors.

The second step of :func:`qr.diagnose.run`, on the cross-fitted labels (:mod:`.labels`): a first
actuator delay by its exact map alone; the selection (:mod:`qr.identification.selection`), where the
roll/pitch torque cannot arbitrate a C_T error fitted on the force rows alone; with a delay named, the
delay by its exact map and the selection again through the late rotor map; the named set fitted, its
block-bootstrap standard errors; the slow torque balance (:mod:`.slow_torque`) for an inertia error the
one-step fit cannot see.  What the held-out part supports is the next step's (:mod:`.held_out`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from ..effects import CATALOG
from ..identification.bootstrap import bootstrap
from ..identification.normal_equations import BlockStats, Columns, fit
from ..identification.selection import ROWS, Arbitration, Selection, select, torque_arbitration
from . import slow_torque as slow_mod
from .core import block_stats, extended_prediction, first_delay, refine_delay, to_parameters
from .labels import Labels, Prepared, at_delay, exact_delay_term
from .settings import DiagnoseConfig
from .wind import WIND, WindMoment, wind_moments


@dataclass(frozen=True)
class NamedEffect:
    """A named effect: its parameters in the catalog's units, their standard errors, its share of the
    held-out residual and the effects it cannot be told apart from."""

    name: str
    parameters: dict[str, float]
    stderr: dict[str, float]
    explained_fraction: float
    confounded_with: list[str]

    def stated(self) -> dict:
        """The effect as ``diagnosis.json`` states it (parameters to 6 significant digits, s.e. to 3)."""
        return {"name": self.name,
                "parameters": {k: float(f"{v:.6g}") for k, v in self.parameters.items()},
                "stderr": {k: float(f"{v:.3g}") for k, v in self.stderr.items()},
                "explained_fraction": float(f"{self.explained_fraction:.4g}"),
                "confounded_with": list(self.confounded_with)}

    def in_vehicle(self) -> dict:
        """The effect as a vehicle file carries it (``effects:``)."""
        return {"name": self.name, "parameters": self.parameters}


@dataclass(frozen=True)
class Fit:
    """What the training part names: the effects, their parameters (``theta``: offsets from each effect's
    neutral value, in the order of ``Columns.of(named)``) and standard errors, and the evidence."""

    labels: Labels  # the labels, the designs reading the rotor map at the fitted delay
    candidates: list[str]
    selection: Selection
    arbitration: Mapping[str, Arbitration]  # effect -> its force- and torque-row estimates, where the roll/pitch
    # torque cannot arbitrate it
    named: list[str]
    theta: np.ndarray
    se: np.ndarray
    force_only: frozenset  # effects fitted on the force rows alone
    stats: BlockStats  # the training part's normal equations of the candidates
    boot_stats: BlockStats  # the bootstrap's (with a delay: the model linearised at its estimate)
    delay_first: float | None  # the first delay estimate (the exact map alone), where actuator_delay is a candidate
    slow: slow_mod.SlowBalance | None = None  # the slow torque balance, where it ran
    # effect -> (parameters, s.e.) from the slow balance, not the fit
    fixed: Mapping[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    explained: Mapping[str, float] = field(default_factory=dict)  # effect -> its share of the held-out loss (.held_out)
    wind: tuple[WindMoment, ...] = ()  # named constant moments the wind's could be (.wind)

    def refit(self, effects: list[str]) -> np.ndarray:
        """One-step fit of ``effects`` on the training part, the slow-balance parameters kept."""
        own = [e for e in effects if e not in self.fixed]
        th_own, own_cols = (fit(self.stats, own) if own else np.zeros(0)), Columns.of(own)
        cols = Columns.of(effects)
        out = np.zeros(cols.size)
        for e in effects:
            out[cols.slices[e]] = self.fixed[e][0] if e in self.fixed else th_own[own_cols.slices[e]]
        return out

    @property
    def effects(self) -> list[NamedEffect]:
        windy = {m.effect for m in self.wind}
        return [NamedEffect(p["name"], p["parameters"], p["stderr"], self.explained[p["name"]],
                            self.selection.confounded.get(p["name"], []) + [WIND] * (p["name"] in windy))
                for p in to_parameters(self.named, self.theta, self.se)]

    def with_wind(self, vehicle) -> Fit:
        """The fit with the named constant moments the wind's could be (:func:`.wind.wind_moments`, on the
        training part)."""
        s = self.labels.full.design_s.take(np.flatnonzero(self.labels.full.train))
        return replace(self, wind=wind_moments(s, vehicle, self.named, self.theta))


def standard_errors(stats: BlockStats, effects: list[str], n_boot: int, seed: int) -> np.ndarray:
    """Block-bootstrap standard errors of ``effects``.  Resampling B blocks underestimates the variance of p
    fitted parameters by (B - p)/B (a sample variance without its degrees-of-freedom correction): the
    s.e. carry that factor back."""
    if not effects:
        return np.zeros(0)
    boot = bootstrap(stats, effects, n_boot, seed)
    used = int(np.count_nonzero(stats.n))
    dof = np.sqrt(used / (used - boot.shape[1])) if used > boot.shape[1] + 1 else 1.0
    return boot.std(axis=0, ddof=1) * dof


def _select(cross: Prepared, vehicle, candidates: list[str], cfg: DiagnoseConfig, force_only=frozenset()):
    """(training statistics, selection, arbitration).  May the roll/pitch torque arbitrate C_T?  Judged
    given what the data do contain (this selection's effects): if the torque rows still put thrust_gain on
    its bound, select again with thrust_gain fitted on the force rows alone."""
    stats, *groups = block_stats(cross, vehicle, Columns.of(candidates, force_only), rows=[None, *ROWS.values()])
    rows = dict(zip(ROWS, groups))
    sel = select(stats, cfg.selection, rows)
    arb = torque_arbitration((rows["force"], rows["torque"]), base=[e for e in sel.named if e != "thrust_gain"]) \
        if "thrust_gain" in candidates and "thrust_gain" not in sel.named and not force_only else {}
    if arb:
        stats, sel, _ = _select(cross, vehicle, candidates, cfg, frozenset(arb))
    return stats, sel, arb


def _fit_named(labels: Labels, vehicle, stats: BlockStats, named: list[str], d, d0, cfg: DiagnoseConfig,
               force_only) -> tuple[np.ndarray, BlockStats, Labels]:
    """The named set's parameters, the statistics its bootstrap resamples, and the labels with the
    full-flight designs at the delay it names (at none: the rotor map on time)."""
    theta = fit(stats, named) if named else np.zeros(0)
    if "actuator_delay" not in named:
        full = labels.full.at_delay(vehicle, d0, shift=0.0) if d is not None else labels.full
        return theta, stats, replace(labels, full=full)
    cross = labels.cross
    d, th_other = refine_delay(cross, vehicle, named, theta, cfg, force_only)
    cols = Columns.of(named)
    theta = theta.copy()
    theta[cols.index([e for e in named if e != "actuator_delay"])] = th_other
    theta[cols.slices["actuator_delay"]] = d
    # the bootstrap repeats the whole estimator, delay search included, to first order: the model
    # linearised at d (a Gauss-Newton step from d, whose fixed point is the estimate)
    s_lin = at_delay(cross, vehicle, d, "tangent")
    y_lin = cross.y - exact_delay_term(cross, vehicle, d) + d * s_lin.delay_column
    boot_stats = block_stats(cross, vehicle, Columns.of(named, force_only), y_lin, s=s_lin)
    # the extended model's other rotor-map effects act d late
    return theta, boot_stats, replace(labels, full=labels.full.at_delay(vehicle, d))


# a C_T error and a mass error are one term in force; a C_T error also scales the roll/pitch torque (the spec)
CT_OR_MASS = {"thrust_gain": "mass_error", "mass_error": "thrust_gain"}


def _balance(f: Fit, vehicle, cfg: DiagnoseConfig, seed: int) -> slow_mod.SlowBalance:
    cross = f.labels.cross
    resid = cross.y - extended_prediction(cross, vehicle, f.named, f.theta, None, f.force_only)
    return slow_mod.slow_torque(cross, vehicle, resid, cfg.slow_torque_horizon, cfg.selection.folds,
                                cfg.selection.t_name, cfg.slow_torque_min_gain, cfg.selection.bootstrap, seed)


def _partner_swapped(f: Fit, cfg: DiagnoseConfig, seed: int) -> tuple[Fit, str, str] | None:
    """The fit with a named C_T (or mass) error swapped for the partner the selection could not tell it from
    (its ``confounded_with``), refitted with its s.e.; None where there is none to swap (or a delay or the
    torque arbitration changed the statistics the swap would need)."""
    if "actuator_delay" in f.named or f.force_only:
        return None
    for e in f.named:
        p = CT_OR_MASS.get(e)
        if p and p in f.selection.confounded.get(e, []) and p not in f.named and p in f.stats.cols.effects:
            named = sorted([p if x == e else x for x in f.named], key=list(CATALOG).index)
            conf = {k: v for k, v in f.selection.confounded.items() if k != e}
            conf[p] = [e] + [c for c in f.selection.confounded[e] if c not in (e, p)]
            sel = replace(f.selection, named=named, confounded=conf)
            return (replace(f, selection=sel, named=named, theta=f.refit(named),
                            se=standard_errors(f.stats, named, cfg.selection.bootstrap, seed)), e, p)
    return None


def _slow_balance(f: Fit, vehicle, cfg: DiagnoseConfig, seed: int, say) -> Fit:
    """The slow torque balance, where an inertia error is a candidate the one-step fit did not name; an
    entry it names joins the named set with the balance's parameters and s.e. (``fixed``).  Where the set
    holds a C_T (or mass) error confounded with its partner, a summed torque residual may be the C_T error's
    torque scaling alone (a payload named as C_T leaves its torque scaled by m/(m + dm)): if the balance
    names nothing with the partner instead, the partner is named, without an inertia error."""
    if not (cfg.slow_torque_horizon and slow_mod.EFFECT in f.candidates and slow_mod.EFFECT not in f.named):
        return f
    say("slow torque balance")
    slow = _balance(f, vehicle, cfg, seed)
    swap = _partner_swapped(f, cfg, seed) if slow.named else None
    if swap is not None:
        g, was, now = swap
        other = _balance(g, vehicle, cfg, seed)
        if not other.named:
            note = (f"with {was} the balance named {', '.join(a.parameter for a in slow.axes if a.named)}; with "
                    f"{now}, the effect the selection could not tell it from, nothing: {now} is named instead")
            return replace(g, slow=replace(other, note=note))
    if not slow.named:
        return replace(f, slow=slow)
    ax = slow.axes
    fixed = {slow_mod.EFFECT: (np.array([a.estimate if a.named else 0.0 for a in ax]),
                               np.array([a.stderr if a.named else np.nan for a in ax]))}
    old = Columns.of(f.named)
    named = sorted(f.named + [slow_mod.EFFECT], key=list(CATALOG).index)
    new = Columns.of(named)
    th, s2 = np.zeros(new.size), np.zeros(new.size)
    for e in named:
        th[new.slices[e]], s2[new.slices[e]] = fixed[e] if e in fixed else (f.theta[old.slices[e]], f.se[old.slices[e]])
    return replace(f, slow=slow, fixed=fixed, named=named, theta=th, se=s2)


def identify(labels: Labels, vehicle, cfg: DiagnoseConfig, seed: int, say) -> Fit:
    """The named set of the training part, fitted (see the module doc)."""
    candidates = [e for e in (cfg.candidates or list(CATALOG)) if e not in cfg.exclude]
    d0 = None
    if "actuator_delay" in candidates:
        say("actuator delay: first estimate")
        d0 = first_delay(labels.cross, vehicle, cfg)
        labels = labels.at_delay(vehicle, d0, shift=0.0)
    say("normal equations")
    say("selection")
    stats, sel, arb = _select(labels.cross, vehicle, candidates, cfg)
    force_only = frozenset(arb) or stats.cols.force_only
    d = None
    if "actuator_delay" in sel.named:
        # a delayed rotor map delays every rotor-map effect (a C_Q error acts on the late yaw torque):
        # with the delay named, the others are judged again through the late rotor map
        say("exact delay")
        d, _ = refine_delay(labels.cross, vehicle, sel.named, fit(stats, sel.named), cfg, force_only)
        labels = labels.at_delay(vehicle, d)
        stats, sel, arb_again = _select(labels.cross, vehicle, candidates, cfg, force_only)
        arb = arb_again or arb
        force_only = stats.cols.force_only
    theta, boot_stats, labels = _fit_named(labels, vehicle, stats, sel.named, d, d0, cfg, force_only)
    say("bootstrap")
    se = standard_errors(boot_stats, sel.named, cfg.selection.bootstrap, seed)
    fitted = Fit(labels, candidates, sel, arb, sel.named, theta, se, force_only, stats, boot_stats, d0)
    return _slow_balance(fitted, vehicle, cfg, seed, say)
