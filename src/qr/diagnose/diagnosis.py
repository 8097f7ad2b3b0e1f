"""One diagnosis: :func:`run` turns the estimates of some flights into a :class:`Diagnosis`.

Built by named steps, each returning a new value (nothing is edited in place):

1. labels (:mod:`.labels`): every segment's residual force and torque, full-flight and cross-fitted;
2. fit (:mod:`.fit`): the selection, the delay, the named set's parameters and standard errors;
3. held-out checks (:mod:`.held_out`): what the held-out part does not support is not named; the named
   model on the held-out part, and whether the model describes the flights at all;
4. replay and rollout (:mod:`.replay`), the learned torque remainder and the check for structure beyond
   the catalog (:mod:`.remainder`), the accelerometer (:mod:`.accelerometer`);
5. what the named effects say of the vehicle file's own numbers (:mod:`.coefficients`).

``diagnosis.json`` is :func:`qr.diagnose.document.document` of it, ``report.md`` and its figures
:mod:`qr.diagnose.report`'s; the stage (:mod:`qr.stages.diagnose`) reads, runs, writes and tracks.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import pandas as pd

from ..config import Group, to_dict
from ..estimation.crossfit import SegmentEstimate
from ..estimation.settings import resolve as resolve_filter
from ..flight import hover_ratio
from ..identification.normal_equations import Columns
from ..intake import Flights
from ..rollout import EvaluateConfig
from ..vehicle import ROTOR_PROPERTIES, Vehicle, vehicle_from_dict
from .accelerometer import AccelerometerCheck, accelerometer_check
from .coefficients import CHECKED_AGAINST, FileFactor, coefficient_checks, evidence
from .core import block_stats
from .fit import Fit, NamedEffect, identify
from .held_out import HeldOutCheck, check_held_out, held_out_support, summed_r2
from .labels import Labels, make_labels
from .remainder import Beyond, TorqueRemainder, fit_torque_remainder, remainder
from .replay import HeldOutRollout, Replays, replay_all, rollout_all
from .settings import DiagnoseConfig

if TYPE_CHECKING:  # (compiled kernels: imported where diagnose.refine=rollout asks for them)
    from .refine import Refinement


@dataclass(frozen=True)
class Settings:
    """What a diagnosis runs with: its settings, the rollout's, the seed, and the settings as given and
    the filter's (recorded in ``diagnosis.json``)."""

    diagnose: DiagnoseConfig
    evaluate: EvaluateConfig = field(default_factory=EvaluateConfig)
    seed: int = 0
    given: Group = field(default_factory=dict)  # the config group ``diagnose`` as composed
    filter: Group = field(default_factory=dict)  # the filter settings the estimates were made with (checked)

    @classmethod
    def composed(cls, overrides) -> Settings:
        """The settings ``qr diagnose`` runs with: the config tree with ``overrides``, every one checked."""
        from ..config import compose_stage

        return cls.of(compose_stage(list(overrides), "diagnose", "diagnose.horizon_s=2"))

    @classmethod
    def of(cls, tree) -> Settings:
        """The settings of a composed config tree (:func:`qr.config.compose_stage`), every one checked."""
        given, filter_cfg = to_dict(tree.diagnose), to_dict(tree.filter)
        resolve_filter(filter_cfg)
        return cls(DiagnoseConfig.from_dict(given), EvaluateConfig.from_dict(to_dict(tree.evaluate)), int(tree.seed),
                   given, filter_cfg)


@dataclass(frozen=True)
class Models:
    """The vehicles a diagnosis makes, in memory (full precision): the nominal one; ``extended``, its
    equation-error effects on the nominal vehicle's own rotor properties (the one-step model); ``refined``,
    the model written with ``diagnose.refine=rollout`` (without its torque remainder); ``hybrid``, the
    extended one plus the learned torque remainder (it was fitted against that model)."""

    nominal: Vehicle
    extended: Vehicle
    refined: Vehicle | None
    hybrid: Vehicle | None


@dataclass(frozen=True)
class Diagnosis:
    """What the nominal model gets wrong on some flights, the causes named, the extended model, the gain."""

    flights: Flights  # names, rows, segments, convention checks
    settings: Settings
    labels: Labels  # the residual labels, the designs at the named delay
    fit: Fit  # the selection and what it names: parameters, s.e., held-out shares
    not_named: dict[str, str]  # effect -> why it is not named though the selection chose it
    held_out: HeldOutCheck  # the named model on the held-out part; misfit: the model does not describe it
    replay: Replays  # the open-loop replay of the nominal and the extended model
    rollout: HeldOutRollout  # the multi-step rollout from the held-out starts, and the share of the residual explained
    remainder: Beyond  # structure beyond the catalog
    accelerometer: AccelerometerCheck | None  # the force label against the accelerometer, where the log has one
    vehicle_file: list[FileFactor]  # statements about the vehicle file's own numbers, where the data identify them
    vehicle_file_unresolved: list[FileFactor]  # the gross factors not stated, each with why
    extended_vehicle: Vehicle  # the nominal vehicle plus the named effects (and the torque remainder); the
    # nominal vehicle on a flight the model does not describe
    torque_remainder: TorqueRemainder | None = None  # the learned torque remainder (a hybrid), where asked
    refinement: Refinement | None = None  # diagnose.refine=rollout, else None
    vehicle: Vehicle = field(kw_only=True)  # the nominal vehicle

    @property
    def effects(self) -> list[NamedEffect]:
        return self.fit.effects

    @property
    def described(self) -> bool:
        return not self.held_out.misfit

    @property
    def verdict(self) -> str:
        """The answer in one paragraph, from the numbers it states."""
        said = " ".join(c.statement[0].upper() + c.statement[1:] + "." for c in self.vehicle_file)
        return _verdict(self) + (" " + said if said else "")

    def models(self) -> Models:
        """:class:`Models`: the nominal, extended, refined and hybrid vehicles."""
        base, raw = self.vehicle, self.extended_vehicle.to_dict()
        remainder = raw.pop("torque_remainder", None)
        # (the refinement may have written other rotor properties: the one-step model keeps the nominal ones)
        one = {k: v for k, v in raw.items() if k not in ROTOR_PROPERTIES}
        one.update({k: base.raw[k] for k in ROTOR_PROPERTIES if k in base.raw})
        one["effects"] = base.effects + [e.in_vehicle() for e in self.effects]
        return Models(base, vehicle_from_dict(one, quiet=True),
                      vehicle_from_dict(raw, quiet=True) if self.refinement is not None else None,
                      vehicle_from_dict({**one, "torque_remainder": remainder}, quiet=True) if remainder else None)


def _verdict(d: Diagnosis) -> str:
    h, misfit = d.held_out, d.held_out.misfit
    if misfit:
        found = "".join(f"Identified {_effect_said(e)}, which alone removes {percent(e.explained_fraction)} of the "
                        "held-out residual. " for e in d.effects)
        return (f"{found}The model does not describe this flight: even extended, the held-out residual is "
                f"{100 * misfit.force_of_weight:.0f} % of the weight in force and "
                f"{100 * misfit.torque_of_weight_at_arm:.0f} % of the weight's torque at the arm "
                f"(a rigid-body model leaves under {100 * misfit.limit:.0f} %), so "
                + ("nothing else is named and nothing is written into the vehicle file. " if d.effects else
                   "nothing is named. ")
                + "Look at the log's frames and units (the convention checks in diagnosis.json), its time stamps and "
                "offsets (qr ingest prints them), the vehicle file (mass, thrust_coeff, rotor_speed_unit, layout) and "
                "events no model holds (ground contact, a tether, a crash).")
    if not d.effects:
        rem = d.remainder
        tail = (f" An unexplained residual remains, correlated with {rem.correlated_with}."
                if rem.structure_remains else "")
        # "up to noise" only when the residual is at the noise floor's level (weighted loss ~ 1)
        fit = ("the nominal model explains this flight up to noise" if h.nominal_loss < 2 else
               "no candidate effect explains the residual, which is well above noise")
        return (f"Nothing named: {fit} (weighted residual {h.nominal_loss:.2f} x the noise floor's variance on "
                f"held-out data).{tail}")
    names = ", ".join(e.name for e in d.effects)
    gain = 1 - h.extended_loss / h.nominal_loss
    windy = "".join(f" {m.effect}: {m.sentence()}." for m in d.fit.wind)
    return (f"Named {names}; the extended model removes {percent(gain)} of the nominal model's weighted "
            f"held-out residual variance (now {h.extended_loss:.2f} x the noise floor's variance); "
            f"{_left_above_noise(h)}.{windy}")


# an axis whose held-out RMSE after extension is at most this many times the noise floor's is "at the noise
# floor" in the verdict (the floor is an estimate: a few tens of per cent above it is within its reach)
AT_NOISE = 1.5
AXIS_NAMES = ("force x", "force y", "force z", "roll torque", "pitch torque", "yaw torque")


def _left_above_noise(h: HeldOutCheck) -> str:
    """Which held-out axes the extension leaves above the noise floor (RMSE ratio, as the report's table):
    a variance removed in bulk by one axis (a mass error's force) can hide torques left at 3x the floor."""
    ratio = [e / f if f > 0 else float("inf") for e, f in zip(h.extended_rmse, h.noise_floor_rmse)]
    above = [(a, r) for a, r in zip(AXIS_NAMES, ratio) if r > AT_NOISE]
    if not above:
        return f"every axis is within {AT_NOISE:g} x the noise floor's RMSE"
    return ("still above the noise floor's RMSE in " + ", ".join(f"{a} ({r:.1f} x)" for a, r in above))


def percent(x: float) -> str:
    """A share in per cent, with the digits it needs never to round to 100 % or 0 % unless it is one of
    them (87 %, 99.6 %, 0.2 %)."""
    p = 100 * x
    for digits in range(6):
        said = f"{p:.{digits}f}"
        if float(said) not in (0.0, 100.0) or p in (0.0, 100.0):
            break
    return f"{said} %"


def _effect_said(e) -> str:
    """``wind_force (fx = 3.43 ± 0.01 N, ...)``: the stated parameters with their s.e. and units."""
    from ..effects import CATALOG

    st = e.stated()
    units = dict(zip(CATALOG[e.name].params, CATALOG[e.name].units))
    par = ", ".join(f"{k} = {v:.3g} ± {st['stderr'].get(k, float('nan')):.2g}"
                    + (f" {units[k]}" if units.get(k, "-") != "-" else "") for k, v in st["parameters"].items())
    return f"{e.name} ({par})"


def _quiet(msg: str) -> None:
    pass


def run(estimates: list[SegmentEstimate], flights: Flights, vehicle, settings: Settings, vehicle_file=None,
        progress=None, on_labels=None) -> Diagnosis:
    """Diagnose ``flights`` from their segments' ``estimates`` (:func:`qr.intake.take`).

    ``vehicle_file``: how statements about the vehicle file name it (default: the vehicle's name);
    ``progress(msg)``: each step as it starts; ``on_labels(prep)``: called with the full-flight labels
    as soon as they exist (the report's residual anatomy is drawn from them while the fit runs).
    """
    say, cfg = progress or _quiet, settings.diagnose
    states, rows = [e.states for e in estimates], [e.rows for e in estimates]
    labels = make_labels(states, [e.halves for e in estimates], vehicle, cfg, on_labels)
    fitted = identify(labels, vehicle, cfg, settings.seed, say)
    supported, not_named = held_out_support(fitted, vehicle, cfg, settings.seed, say)
    final, held_out, dropped = check_held_out(supported, vehicle, cfg, settings.seed)
    final = final.with_wind(vehicle)
    effects = [e.in_vehicle() for e in final.effects]
    say("replay")
    replay = replay_all(states, rows, vehicle, effects, cfg.horizon_s, final.labels.full.windows)
    extended = vehicle.with_changes(effects=vehicle.effects + effects)
    # (no learned remainder on a flight the model does not describe: nothing is written into the vehicle)
    torque_rem, hybrid = _torque_remainder(final, extended, vehicle, flights, cfg.torque_remainder_ridge, say) \
        if not held_out.misfit else (None, None)
    rollout, beyond, accelerometer = _after_the_fit(states, rows, vehicle, final, held_out, effects, hybrid,
                                                    settings, say)
    refinement, written = _refined(states, rows, vehicle, final, hybrid or extended, settings, say,
                                   described=not held_out.misfit)
    statements, unresolved = _vehicle_file(final, vehicle, vehicle_file or vehicle.name, flights)
    if held_out.misfit:  # what the flight shows is stated; nothing of it goes into the vehicle, or about its file
        written, statements, unresolved = vehicle, [], []
    return Diagnosis(flights, settings, final.labels, final, {**not_named, **dropped}, held_out, replay, rollout,
                     beyond, accelerometer, statements, unresolved, written, torque_rem, refinement, vehicle=vehicle)


def _refined(states, rows, vehicle, final: Fit, extended: Vehicle, settings: Settings, say,
             described: bool = True):
    """(the refinement by simulation error, the vehicle written): with ``diagnose.refine=rollout`` the named
    effects' parameters and the vehicle's J, C_T, C_Q refined by the rollout's error
    (:mod:`qr.diagnose.refine`), as far as it may write them; else (None, ``extended``).  Not on flights
    the model does not describe (``described`` false: the held-out misfit): no coefficient of it is written."""
    if settings.diagnose.refine != "rollout" or not described:
        return None, extended
    from .refine import refine_diagnosis

    named = [{"name": e.name, "parameters": e.parameters, "stderr": e.stderr} for e in final.effects]
    refinement = refine_diagnosis(states, rows, final.labels.full.windows, vehicle, named, settings.diagnose,
                                  settings.evaluate, settings.seed, say)
    return refinement, extended.with_changes(effects=vehicle.effects + refinement.effects(
        [e.in_vehicle() for e in final.effects]), **refinement.properties())


def _torque_remainder(final: Fit, extended: Vehicle, vehicle, flights: Flights, ridge: float,
                      say) -> tuple[TorqueRemainder | None, Vehicle | None]:
    """The learned torque remainder (``ridge`` > 0) and the extended vehicle carrying it (the hybrid)."""
    if ridge <= 0:
        return None, None
    say("fitting the learned torque remainder")
    rem = fit_torque_remainder(final, vehicle, ridge)
    note = (f"learned on the training part of {', '.join(Path(f).name for f in flights.names)} (ridge {ridge:g}): "
            "not a physical effect")
    return rem, extended.with_changes(torque_remainder=rem.in_vehicle(vehicle, note))


def _vehicle_file(final: Fit, vehicle, vehicle_file, flights: Flights) -> tuple[list[FileFactor], list[FileFactor]]:
    """Statements about the vehicle file's own numbers (:func:`coefficient_checks`), from the parameters
    as diagnosis.json states them and the log's hover balance."""
    hover = hover_ratio(pd.concat(flights.measured, ignore_index=True), vehicle)
    stats = final.stats
    own = [e for e in final.named if e not in final.fixed]
    checks = [c for e, c in CHECKED_AGAINST.items() if e in own and c not in final.named]
    if any(c not in stats.cols.effects for c in checks):
        # a C_Q or inertia factor is checked against a rate damping, a candidate or not
        stats = block_stats(final.labels.cross, vehicle, Columns.of(own + checks, final.force_only))
    return coefficient_checks([e.stated() for e in final.effects], vehicle, vehicle_file,
                              evidence(stats, final.named, final.fixed), hover)


def _after_the_fit(states, rows, vehicle, final: Fit, held_out: HeldOutCheck, effects, hybrid, settings: Settings,
                   say) -> tuple[HeldOutRollout, Beyond, AccelerometerCheck | None]:
    """(rollout, structure beyond the catalog, accelerometer check).  The check for structure beyond the
    catalog (numpy) runs beside the rollout (compiled, the GIL released): neither reads what the other
    writes."""
    cfg, ecfg, full = settings.diagnose, settings.evaluate, final.labels.full
    with ThreadPoolExecutor(1) as pool:
        checked = pool.submit(remainder, final, vehicle, cfg)
        say("rolling out the nominal and the extended model on the held-out part")
        y_test = full.y[full.test]
        explained = summed_r2(full, y_test, y_test - held_out.prediction, ecfg.horizon)
        rollout = rollout_all(states, rows, vehicle, effects, full.windows, ecfg.horizon, ecfg.max_input_gap, 0.0,
                              explained, hybrid)
        accelerometer = accelerometer_check(states, rows, vehicle, cfg.trim_s)
        say("checking for structure beyond the catalog")
        return rollout, checked.result(), accelerometer
