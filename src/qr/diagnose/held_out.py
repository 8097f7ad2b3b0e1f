"""The held-out checks, the third step of :func:`qr.diagnose.run`: a named effect the cross-fitted held-out rows
do not support is dropped (:func:`held_out_support`, :func:`unsupported`); on the full-flight held-out rows the
nominal and extended residuals, noise floor and anatomy (:func:`check_held_out`); a flight the model does not
describe (beyond ``MISFIT``) gets only its largest effect stated (:func:`largest_effect`), nothing written.
docs/diagnose.md "A flight the model does not describe".
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from ..identification.edge import EDGE, Margins
from ..identification.normal_equations import BlockStats, Columns, fit
from ..effects import CATALOG, Signals
from . import slow_torque as slow_mod
from .core import block_stats, extended_prediction, predict, rms
from .fit import Fit, standard_errors
from .labels import Prepared, weights
from .settings import DiagnoseConfig

AXES_SAID = ("f_x", "f_y", "f_z", "τ_x", "τ_y", "τ_z")
# A rigid-body model with the catalog's effects describes a flight whose held-out residual, after the best
# extension, stays below this share of the weight (force) and of the weight's torque at the arm (torque):
# drag, biases and rotor errors of any real quadrotor leave a few per cent (the measured Crazyflie flights:
# 1-7 %); a log in another frame or unit, a tether, a crash leave tens of per cent or more.
MISFIT = 0.1


def misfit_shares(resid: np.ndarray, vehicle) -> tuple[float, float]:
    """The held-out residual (N, 6) as shares of the vehicle's scales: RMS force over the weight, RMS torque
    over the weight's torque at the arm."""
    arm = float(np.max(np.hypot(*vehicle.rotors.positions.T)))
    weight = vehicle.mass * 9.81
    force = float(np.sqrt(np.nanmean(np.nansum(resid[:, :3] ** 2, axis=1)))) / weight
    torque = float(np.sqrt(np.nanmean(np.nansum(resid[:, 3:] ** 2, axis=1)))) / (weight * arm)
    return force, torque


@dataclass(frozen=True)
class Misfit:
    """The model does not describe the flights: the held-out residual's force (share of the weight) and torque
    (share of the weight's torque at the arm), beyond ``limit``."""

    force_of_weight: float
    torque_of_weight_at_arm: float
    limit: float

    def record(self) -> dict:
        return {"force_of_weight": self.force_of_weight, "torque_of_weight_at_arm": self.torque_of_weight_at_arm,
                "limit": self.limit}


def model_misfit(resid: np.ndarray, vehicle) -> Misfit | None:
    """Where the held-out residual (N, 6) is beyond ``MISFIT`` of the vehicle's scales: the shares; else None."""
    force, torque = misfit_shares(resid, vehicle)
    if max(force, torque) <= MISFIT:
        return None
    return Misfit(force, torque, MISFIT)


class HeldOut:
    """The held-out rows of a prepared data set, and what a named set explains there."""

    def __init__(self, prep: Prepared, vehicle, force_only, fixed, slow: slow_mod.SlowBalance | None):
        self.prep, self.vehicle, self.force_only, self.fixed, self.slow = prep, vehicle, force_only, fixed, slow
        self.idx = np.flatnonzero(prep.test)
        self.s = prep.design_s.take(self.idx)
        self.y = prep.y[self.idx]
        self.w = weights(prep.sd)[self.idx]
        self.base = float(np.nanmean(self.w * self.y**2))
        half = (self.idx >= prep.pair_offset) if prep.pair_offset else np.zeros(len(self.idx), bool)
        self.group = prep.flight[self.idx] * 2 + half  # a window never joins the two cross-fitting halves

    def residual(self, named, theta) -> np.ndarray:
        return self.y - extended_prediction(self.prep, self.vehicle, named, theta, self.idx, self.force_only)

    def summed(self, r: np.ndarray) -> float:
        """The torque residual summed over the slow balance's horizon (what it judges on), in noise units."""
        sums, _ = slow_mod.window_sums(r[:, 3:6], self.group, self.slow.horizon)
        return float(np.sum(sums**2 / np.nanmedian(self.prep.sd[self.idx, 3:6], axis=0) ** 2))

    def explained(self, named, theta, refit) -> dict:
        """Each effect's share of the held-out loss: the named set refitted without it, against the whole
        set; an effect the slow torque balance named (``fixed``), its share of the held-out torque
        residual summed over the balance's horizon, as it was judged."""
        resid = self.residual(named, theta)
        ext = float(np.nanmean(self.w * resid**2))
        out = {}
        for e in named:
            rest = [x for x in named if x != e]
            r_rest = self.y - predict(self.s, self.vehicle, rest, refit(rest) if rest else np.zeros(0),
                                      self.force_only)
            if e in self.fixed:
                out[e] = (self.summed(r_rest) - self.summed(resid)) / self.summed(self.y)
            else:
                out[e] = float((np.nanmean(self.w * r_rest**2) - ext) / self.base)
        return out


def unsupported(named, explained, y, resid, w, min_gain, resid_without) -> tuple[str, str] | None:
    """The named effect the held-out data do not support, and why; None if every one is.

    An effect whose held-out share is zero or less explains nothing there (the lowest such first).  A
    held-out axis the named set leaves worse than the nominal model, by more than ``min_gain`` of its
    loss and by more than the noise floor's variance (the weights' unit; below it, regressor noise the
    extended model adds on an axis the nominal model already fits to noise): the effect whose removal helps
    that axis most (two effects that cancel where the flight spends its time fit the training part's
    small differences, and the held-out part pays for it).
    """
    if not named:
        return None
    weak = min(named, key=lambda e: (explained[e], e))
    if explained[weak] <= EDGE:  # (a share within numerical noise of zero is none)
        return weak, f"it explains {100 * explained[weak]:.2g} % of the held-out residual"
    nominal, ext = np.nanmean(w * y**2, axis=0), np.nanmean(w * resid**2, axis=0)
    worse = np.flatnonzero([Margins().at_least(a, (1 + min_gain) * b, on_edge=True) and
                            Margins().at_least(a - b, 1.0, on_edge=True) for a, b in zip(ext, nominal)])
    if not worse.size:
        return None
    j = int(worse[np.argmax(ext[worse] / nominal[worse])])
    helps = {e: float(np.nanmean(w[:, j] * resid_without([x for x in named if x != e])[:, j] ** 2)) for e in named}
    e = min(helps, key=helps.get)
    return e, (f"with it the held-out {AXES_SAID[j]} residual is {ext[j] / nominal[j]:.3g} x the nominal model's "
               f"({helps[e] / nominal[j]:.3g} x without it)")


# An axis's residual variance must exceed the noise floor's by this fraction of it before the anatomy
# shares it out: the floor is an estimate, and a few per cent of it is within its own uncertainty.
ANATOMY_MIN_SIGNAL = 0.05


def anatomy(stats: BlockStats, s_test: Signals, y_test: np.ndarray, sd_test: np.ndarray, vehicle,
            candidates: list[str], force_only=()) -> dict:
    """Share of each axis's held-out residual variance that each candidate explains alone (fit on train).

    Net of the noise floor: a share of 1 would leave only noise.  Negative: it does worse than nothing.
    NaN for an axis at the noise floor: its residual variance exceeds the noise variance by less than
    ``ANATOMY_MIN_SIGNAL`` of it, so there is nothing above noise to share out (dividing by that
    difference would print noise as huge shares).
    """
    out = {}
    base = np.nanmean(y_test**2, axis=0)
    noise = np.nanmean(sd_test**2, axis=0)
    signal = base - noise
    above = signal > ANATOMY_MIN_SIGNAL * noise
    for e in candidates:
        pred = predict(s_test, vehicle, [e], fit(stats, [e]), force_only)
        gain = base - np.nanmean((y_test - pred) ** 2, axis=0)
        out[e] = np.divide(gain, signal, out=np.full(len(gain), np.nan), where=above).tolist()
    return out


@dataclass(frozen=True)
class Explained:
    """Share of the held-out residual the extended model explains, per axis: sample by sample, and summed over
    windows of ``horizon`` samples (:func:`summed_r2`)."""

    one_step: list[float]
    summed: list[float]
    horizon: int

    def record(self) -> dict:
        return {"one_step": self.one_step, "summed": self.summed, "horizon": self.horizon}


def summed_r2(prep: Prepared, y: np.ndarray, resid: np.ndarray, horizon: int) -> Explained:
    """Share of the held-out residual the extended model explains, per axis: sample by sample, and summed
    over windows of ``horizon`` samples (what a rollout integrates: a slow torque error held for the
    horizon), never across a segment's edge; windows holding a missing label are left out."""
    test = np.flatnonzero(prep.test)
    num1, den1 = np.nansum(resid**2, axis=0), np.nansum(y**2, axis=0)
    k = y.shape[1]
    sums, _ = slow_mod.window_sums(np.hstack([y, resid]), prep.flight[test], horizon)
    den, num = (sums[:, :k] ** 2).sum(axis=0), (sums[:, k:] ** 2).sum(axis=0)
    return Explained((1 - num1 / np.where(den1 > 0, den1, np.nan)).tolist(),
                     (1 - num / np.where(den > 0, den, np.nan)).tolist(), int(horizon))


def _without(f: Fit, e: str, vehicle, cfg: DiagnoseConfig, seed: int) -> Fit:
    """``f`` without effect ``e``: the rest refitted, their s.e. from their own bootstrap."""
    old = Columns.of(f.named)
    named = [x for x in f.named if x != e]
    if e == "actuator_delay":  # the other effects act on the rotor map on time again
        labels = f.labels.at_delay(vehicle, f.delay_first, shift=0.0)
        stats = block_stats(labels.cross, vehicle, Columns.of(f.candidates, f.force_only))
        f = replace(f, labels=labels, stats=stats, boot_stats=stats)
    theta, se = f.refit(named), f.se[old.index(named)]
    own = [x for x in named if x not in f.fixed]
    if own:  # standard errors of the smaller set's own fit, as for the named set
        se_own, own_cols, new = standard_errors(f.boot_stats, own, cfg.selection.bootstrap, seed), Columns.of(own), \
            Columns.of(named)
        for x in own:
            se[new.slices[x]] = se_own[own_cols.slices[x]]
    return replace(f, named=named, theta=theta, se=se)


def held_out_support(f: Fit, vehicle, cfg: DiagnoseConfig, seed: int, say) -> tuple[Fit, dict[str, str]]:
    """The fit of what the held-out part supports (each effect's share in ``explained``), and the named
    effects it does not support, each with why (dropped one at a time, the named set refitted each time)."""
    judge = HeldOut(f.labels.cross, vehicle, f.force_only, f.fixed, f.slow)
    dropped = {}
    while True:
        explained = judge.explained(f.named, f.theta, f.refit)
        why = unsupported(f.named, explained, judge.y, judge.residual(f.named, f.theta), judge.w,
                          cfg.selection.min_gain, lambda rest: judge.residual(rest, f.refit(rest)))
        if not why:
            return replace(f, explained=explained), dropped
        e, reason = why
        dropped[e] = reason
        say(f"not named: {e} ({reason})")
        f = _without(f, e, vehicle, cfg, seed)
        if e == "actuator_delay":
            judge = HeldOut(f.labels.cross, vehicle, f.force_only, f.fixed, f.slow)


@dataclass(frozen=True)
class HeldOutCheck:
    """The named model on the held-out rows of the full-flight labels (per axis: f_x, f_y, f_z, τ_x, τ_y, τ_z)."""

    nominal_rmse: list[float]
    extended_rmse: list[float]
    noise_floor_rmse: list[float]
    nominal_loss: float  # weighted by the noise floor: 1 = the residual is noise
    extended_loss: float
    prediction: np.ndarray  # the named effects' terms on the held-out rows
    misfit: Misfit | None  # where the model does not describe the flights (:func:`model_misfit`)
    anatomy: Mapping[str, list[float]]  # candidate -> share of each axis's held-out residual it explains alone


MISFIT_REASON = "the model does not describe this flight, so no effect is a finding"
BESIDE_LARGEST = ("the model does not describe this flight: only its largest effect is stated (beside it, the "
                  "catalog's terms may stand in for what the model lacks)")
# On a flight the model does not describe, the largest effect is stated when, fitted alone on the training
# part, it removes at least this share of the held-out residual (noise-weighted): it is then most of what
# the flight shows, and the part the model lacks can bias it by less than it explains (chosen).
LARGEST_MIN_SHARE = 0.5


def largest_effect(f: Fit, vehicle, cfg: DiagnoseConfig, seed: int) -> tuple[Fit, dict[str, str]]:
    """On a flight the model does not describe: the fit of its largest effect alone, and why each other
    effect of ``f`` is not stated.

    The largest effect is the selection's first (the single effect that cuts the cross-validated loss
    most, as the selection accepted it), fitted alone on the training part, with its block-bootstrap standard errors and its share of the
    held-out residual alone (``explained``).  It is stated when (1) that share is at least
    ``LARGEST_MIN_SHARE`` and (2) the rows it acts on (force, torque) are described with it alone: their
    held-out residual within ``MISFIT`` of the vehicle's scale, what the model lacks on the other rows (a
    wind of half the weight beside a torque the catalog has no term for).  A log in another convention
    fails (2) (a scalar-last quaternion's "wind" leaves the force at 38 % of the weight): what the model
    lacks then sits in the effect's own rows and biases it.  Only the largest: the closed loop makes the
    part the model lacks correlate with the catalog's other terms (the tilt the controller holds against
    an unmodelled force times a vertical wind mimics that force), so a larger set trades its parameters
    against it."""
    first = next((s["effects"] for s in f.selection.path if s["size"] == 1 and s.get("accepted")), None)
    if first:
        e = first[0]
        judge = HeldOut(f.labels.cross, vehicle, f.force_only, f.fixed, f.slow)
        theta = f.refit([e])
        share = float((judge.base - np.nanmean(judge.w * judge.residual([e], theta) ** 2)) / judge.base)
        prep = f.labels.full
        test = np.flatnonzero(prep.test)
        left = misfit_shares(prep.y[test] - extended_prediction(prep, vehicle, [e], theta, test, f.force_only),
                             vehicle)
        acts = (min(CATALOG[e].axes) < 3, max(CATALOG[e].axes) >= 3)  # on the force rows, the torque rows
        m = Margins()
        if m.at_least(share, LARGEST_MIN_SHARE, on_edge=False) and \
                all(m.at_most(x, MISFIT, on_edge=False) for x, on in zip(left, acts) if on):
            se = f.fixed[e][1] if e in f.fixed else standard_errors(f.stats, [e], cfg.selection.bootstrap, seed)
            return (replace(f, named=[e], theta=theta, se=se, explained={e: share}),
                    {x: BESIDE_LARGEST for x in f.named if x != e})
        why = {e: f"{MISFIT_REASON}: its largest effect alone removes {100 * share:.3g} % of the held-out residual "
                  f"and leaves {100 * left[0]:.3g} % of the weight in force, {100 * left[1]:.3g} % of the weight's "
                  "torque at the arm (stated only above half of the residual, with the rows it acts on within "
                  f"{100 * MISFIT:.0f} %)"}
        return replace(f, named=[], theta=np.zeros(0), se=np.zeros(0)), \
            {**{x: MISFIT_REASON for x in f.named}, **why}
    return replace(f, named=[], theta=np.zeros(0), se=np.zeros(0)), {x: MISFIT_REASON for x in f.named}


def check_held_out(f: Fit, vehicle, cfg: DiagnoseConfig, seed: int) -> tuple[Fit, HeldOutCheck, dict[str, str]]:
    """The held-out check of ``f``; where the model does not describe the flights (:func:`model_misfit`
    of the named set's residual), the fit of their largest effect alone (:func:`largest_effect`), each
    other effect given why it is not stated."""
    prep = f.labels.full
    test = np.flatnonzero(prep.test)
    y_test, sd_test, w_test = prep.y[test], prep.sd[test], weights(prep.sd)[test]
    pred = extended_prediction(prep, vehicle, f.named, f.theta, test, f.force_only)
    misfit = model_misfit(y_test - pred, vehicle)
    dropped = {}
    if misfit:  # the catalog's best extension is no finding on a flight the model does not describe
        f, dropped = largest_effect(f, vehicle, cfg, seed)
        pred = extended_prediction(prep, vehicle, f.named, f.theta, test, f.force_only) if f.named \
            else np.zeros_like(y_test)
    resid = y_test - pred
    return f, HeldOutCheck(
        nominal_rmse=rms(y_test).tolist(), extended_rmse=rms(resid).tolist(), noise_floor_rmse=rms(sd_test).tolist(),
        nominal_loss=float(np.nanmean(w_test * y_test**2)), extended_loss=float(np.nanmean(w_test * resid**2)),
        prediction=pred, misfit=misfit,
        anatomy=anatomy(f.stats, prep.design_s.take(test), y_test, sd_test, vehicle, f.candidates, f.force_only)), \
        dropped
