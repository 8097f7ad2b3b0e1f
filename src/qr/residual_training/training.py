"""``run``: the flights' windows, the training, the ensemble, the validation scores -> :class:`ResidualTraining`."""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from .. import holdout
from .. import residual_fit as rf
from ..config import Group, to_dict
from ..ensemble import Member
from ..errors import QrInputError
from ..flightsets import FlightInfo
from ..residual import Residual, Size
from ..rollout import QUANTITIES, EvaluateConfig
from ..vehicle import Vehicle
from .sentences import kept_sentence, split_sentence

if TYPE_CHECKING:
    from ..bands import Scale

COMMAND_KEYS = ("flights", "vehicle", "out", "force")  # learn.* keys of the command line, not settings


@dataclass(frozen=True)
class Settings:
    """What a training runs with: the network's and the rollout's settings, the seed, the filter's, and the
    settings as composed (training.json's ``config``)."""

    learn: rf.ResidualConfig
    evaluate: EvaluateConfig
    seed: int
    filter: Group  # the filter settings the estimates are made with (checked)
    given: Group  # learn (less the command line's keys), evaluate and filter as composed

    @classmethod
    def of(cls, tree, split: holdout.SplitConfig | None = None) -> Settings:
        """The settings of a composed tree, every one checked; ``split`` replaces ``evaluate.split``."""
        from ..estimation.settings import resolve as resolve_filter

        plain = to_dict(tree)
        learn = rf.ResidualConfig.from_dict(plain["learn"])
        ecfg = EvaluateConfig.from_dict(plain["evaluate"])
        resolve_filter(plain["filter"])
        if split is not None:
            ecfg = replace(ecfg, split=split)
            plain["evaluate"]["split"] = asdict(split)  # training.json says the split it was trained under
        given = {"learn": {k: v for k, v in plain["learn"].items() if k not in COMMAND_KEYS},
                 "evaluate": plain["evaluate"], "filter": plain["filter"]}
        return cls(learn, ecfg, int(plain.get("seed", 0)), plain["filter"], given)


@dataclass(frozen=True)
class ValidationSplit:
    """Which flights train and which stop the training (:func:`qr.residual_fit.split`)."""

    by: str  # flight | trajectory | time (a lone flight: its last time block validates)
    training: tuple[str, ...]
    validation: tuple[str, ...]
    validation_from_s: float | None  # by time: where the validation block starts

    def record(self) -> dict:
        """:func:`qr.residual_fit.split`'s form (the sentences' input)."""
        return {"by": self.by, "training": list(self.training), "validation": list(self.validation),
                **({"validation_from_s": self.validation_from_s} if self.by == "time" else {})}


@dataclass(frozen=True)
class Validation:
    """The compiled rollout of ``qr evaluate`` on the validation windows, per model (rate_frozen, vehicle,
    hybrid) and signal."""

    steps: tuple[int, ...]  # the steps h recorded (1, 10, H)
    mae: Mapping[str, Mapping[str, Mapping[int, float | None]]]  # model -> signal -> h -> MAE
    ratio: Mapping[str, Mapping[str, float | None]]  # model -> signal -> MAE / rate_frozen's at h = H

    @classmethod
    def of(cls, blocks: dict, H: int) -> Validation:
        from ..rollout import at

        hs = tuple(sorted({h for h in (1, 10, H) if h <= H}))
        ref = blocks["rate_frozen"]
        return cls(hs, {m: {q: {h: at(b, h, q) for h in hs} for q in QUANTITIES} for m, b in blocks.items()},
                   {m: {q: (None if at(b, H, q) is None or not at(ref, H, q) else at(b, H, q) / at(ref, H, q))
                        for q in QUANTITIES} for m, b in blocks.items()})

    def metrics(self) -> dict[int, dict[str, float | None]]:
        """What MLflow logs of the vehicle and the hybrid, by step: the ratios at H (step 0), the MAE per h
        (step h)."""
        models = ("vehicle", "hybrid")
        return {0: {f"val.{m}.{q}_ratio": self.ratio[m][q] for m in models for q in QUANTITIES},
                **{h: {f"val.{m}.{q}_mae": self.mae[m][q][h] for m in models for q in QUANTITIES}
                   for h in self.steps}}


@dataclass(frozen=True)
class Ensemble:
    """The band's members, each fine-tuned from the network on a resample of the training flights."""

    members: tuple[Member, ...]
    scale: Scale | None  # the band's scale per signal (qr.bands.calibrate), None without validation windows
    scale50: Scale | None  # the 50 % band's
    calibrated_on: str
    wall_s: float
    jobs: int  # processes that trained them


@dataclass(frozen=True)
class ResidualTraining:
    """A residual trained through the rollout on top of a vehicle, and how it was trained."""

    flights: tuple[str, ...]  # as given
    vehicle_file: str
    settings: Settings
    split: ValidationSplit
    trained: rf.Trained  # the network, the loss per epoch, the kept epoch
    fine_tuned: bool  # the vehicle carried a residual, the start of the training
    physical: Vehicle  # the vehicle without a residual
    residual: Residual  # the trained network
    validation: Validation
    size: Size  # the wrench's RMS over the training windows
    estimate_s: float  # wall time of the flights' estimates
    ensemble: Ensemble | None

    @property
    def horizon(self) -> int:
        return self.settings.learn.horizon

    @property
    def signal_weights(self) -> dict[str, float]:
        return dict(zip(QUANTITIES, self.settings.learn.signal_weights.vector().tolist()))

    @property
    def note(self) -> str:
        """The vehicle file's note on the residual."""
        return (f"trained through the {self.horizon}-step rollout on {', '.join(self.split_training)} "
                "by qr learn residual: a learned wrench, not a physical effect")

    @property
    def split_training(self) -> list[str]:
        return [f for f in self.flights if f in self.split.training]

    def hybrid_file(self, model) -> dict:
        """The hybrid vehicle file's mapping (``model``: where the weights are written)."""
        from .. import residual as rs

        raw = self.physical.to_dict()
        raw["residual"] = rs.block(self.residual, str(model.resolve()), self.note, self.size)
        return raw

    @property
    def header(self) -> str:
        return (f"Hybrid vehicle from qr learn residual on {', '.join(self.split_training)}: {self.vehicle_file} "
                "plus a learned wrench (residual.npz)")


def check_flights(flights: list[str], settings: Settings) -> dict[str, FlightInfo]:
    """What the flights fly (``evaluate.split``); a flight given twice, or one the split scores, is refused
    before any flight is read (training on a scored flight would score a trained flight)."""
    if len(set(flights)) < len(flights):
        dup = next(f for f in flights if flights.count(f) > 1)
        raise QrInputError(dup, "the same flight is given twice", "give each flight once")
    split = settings.evaluate.split
    infos = split.infos(flights)
    scored = [f for f in flights if infos and holdout.named(infos[f], split)]
    if scored:
        raise QrInputError(scored[0], f"evaluate.split scores this flight ({infos[scored[0]].describe()}): "
                           "training on it would score a trained flight", "leave it out of the training flights")
    return infos


def run(flights: list[str], measured: list, infos: dict[str, FlightInfo], vehicle: Vehicle, vehicle_file: str,
        settings: Settings, reports: list | None = None, estimates: list | None = None,
        say=lambda msg: None, memo=None) -> ResidualTraining:
    """Train on ``flights`` (``measured``: their rows; ``infos``: :func:`check_flights`) on top of ``vehicle``.
    ``reports`` / ``estimates``: the filter stage's report and cross-fit file of each flight; ``memo``: what an
    earlier command of this process took (:class:`qr.intake.Memo`)."""
    from ..pieces import rollout_pieces
    from ..rollout import windows
    from ..vehicle import vehicle_from_dict

    rcfg, ecfg = settings.learn, settings.evaluate
    if not rcfg.keep_remainder and "torque_remainder" in vehicle.raw:
        raw = vehicle.to_dict()
        raw.pop("torque_remainder")
        vehicle = vehicle_from_dict(raw, vehicle_file)
    t0 = time.perf_counter()
    cut = rollout_pieces(flights, measured, vehicle, ecfg, settings.filter, reports, estimates, say, vehicle_file, memo)
    pieces = [(f, windows(st, meas, rcfg.horizon, ecfg.max_input_gap, keep)) for f, ps in zip(flights, cut)
              for st, meas, keep in ps]
    estimate_s = time.perf_counter() - t0
    _, val, by = holdout.validation(flights, ecfg.split, rcfg.validation, infos)
    parts, split = rf.split(pieces, rcfg.horizon, rcfg.validation, rcfg.stride, val, by)
    say(split_sentence(split))
    fine_tuned = getattr(vehicle, "residual", None) is not None
    trained = rf.train(rcfg, vehicle, parts, settings.seed, say)
    if trained.best_epoch == 0:
        say(kept_sentence(trained.initial["val_loss"], [e["val_loss"] for e in trained.epochs], fine_tuned))
    raw = vehicle.to_dict()
    raw.pop("residual", None)
    physical = vehicle_from_dict(raw)  # the vehicle without a residual (a fine-tuned one is replaced)
    res = trained.net.to_residual()
    hybrid = physical.with_changes()
    hybrid.residual = res
    blocks = rf.validation_blocks(parts, {"vehicle": physical, "hybrid": hybrid}, rcfg.horizon)
    size = training_size(res, parts, rcfg.horizon, physical)
    band = _ensemble(settings, physical, hybrid, parts, split["training"], trained, say) if rcfg.members else None
    return ResidualTraining(tuple(flights), str(vehicle_file), settings,
                            ValidationSplit(split["by"], tuple(split["training"]), tuple(split["validation"]),
                                            split.get("validation_from_s")),
                            trained, fine_tuned, physical, res, Validation.of(blocks, rcfg.horizon), size, estimate_s,
                            band)


def _ensemble(settings: Settings, physical: Vehicle, hybrid: Vehicle, parts: list, training: list[str],
              trained: rf.Trained, say) -> Ensemble:
    from .. import ensemble

    rcfg = settings.learn
    t1 = time.perf_counter()
    members, jobs = ensemble.train_members(rcfg, hybrid, parts, training, settings.seed, rcfg.members, say,
                                           trained.wall_s / max(len(trained.epochs), 1))
    scale, scale50, where = ensemble.calibrated(physical, hybrid, members, parts, settings.evaluate.horizon)
    return Ensemble(tuple(members), scale, scale50, where, time.perf_counter() - t1, jobs)


def training_size(res: Residual, parts: list, H: int, vehicle: Vehicle) -> Size:
    """The trained wrench's RMS over every sample of the training windows (:func:`qr.residual.rms_size`): the
    size ``qr export`` states where a simulator has no place for the network.  States are the filter's
    estimates moved from the tracked point to the CG; rotor speeds those acting there (delay applied)."""
    from .. import residual as rs
    from ..frames import quat_to_rot, to_body
    from ..plant_state import P_MARKER, X_QUAT, X_RATE, X_VEL
    from ..sim.plant import cg_from_tracked, true_params

    P = true_params(vehicle, vehicle.effects, residual=False)
    r = P[P_MARKER].copy()
    X, U, flights = [], [], []
    for pc in parts:
        if not len(pc.train):
            continue
        w = pc.windows
        edge = np.zeros(len(w.t) + 1, int)  # samples s … s + H of each training window
        np.add.at(edge, pc.train, 1)
        np.add.at(edge, np.minimum(pc.train + H + 1, len(w.t)), -1)
        take = np.cumsum(edge[:-1]) > 0
        x = w.X0[take].copy()
        for row in x:
            cg_from_tracked(row, r)
        X.append(x)
        U.append(w.inputs(P)[take])
        flights += [pc.flight] if pc.flight not in flights else []
    X = np.concatenate(X) if X else np.zeros((0, 13))
    U = np.concatenate(U) if U else np.zeros((0, 4))
    R = quat_to_rot(X[:, X_QUAT]) if len(X) else np.zeros((0, 3, 3))
    return rs.rms_size(res, to_body(R, X[:, X_VEL]), X[:, X_RATE], R[:, 2, :] * -1.0, U, flights)
