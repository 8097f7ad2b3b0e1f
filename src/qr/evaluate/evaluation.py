"""One evaluation: :func:`run` rolls vehicle models out from every start of the scored flights' pieces
(docs/spec/evaluate.md) into an :class:`Evaluation`.

Each piece (an airborne, gap-free segment less ``evaluate.trim_s`` at both ends, its start states from the
filter stage's estimate) is scored for the references ``hold`` and ``rate_frozen`` and each model
(:func:`qr.rollout.score`); with training flights, every window is checked against their envelope
(:mod:`qr.envelope`); a model with a known uncertainty carries a band (:mod:`qr.bands`).
``evaluation.json`` is :func:`qr.evaluate.document.document` of it, ``report.md`` and the figures
:func:`qr.evaluate.report.write`'s; the stage (:mod:`qr.stages.evaluate`) reads, runs, writes and tracks.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .. import rollout
from ..bands import Bands, BandSet
from ..config import Group, to_dict
from ..envelope import Envelope, Outside, check
from ..errors import QrInputError
from ..estimation.nis import NisReport
from ..estimation.settings import resolve as resolve_filter
from ..holdout import Assignment, assign
from ..intake import shown
from ..rollout import REFERENCES, EvaluateConfig
from ..vehicle import Vehicle

Piece = tuple[pd.DataFrame, pd.DataFrame, np.ndarray]  # (estimated states, measured rows, the starts kept)
Sums = tuple[np.ndarray, np.ndarray]  # (H, 4) each: the absolute errors summed per step and quantity, the windows


@dataclass(frozen=True)
class Settings:
    """What an evaluation runs with: ``evaluate`` (checked), and as given the config group ``evaluate`` and the
    filter settings the estimates were made with (both recorded in ``evaluation.json``)."""

    evaluate: EvaluateConfig
    given: Group
    filter: Group

    @classmethod
    def of(cls, tree) -> Settings:
        """The settings of a composed config tree (:func:`qr.config.compose_stage`), every one checked."""
        filter_cfg = to_dict(tree.filter)
        resolve_filter(filter_cfg)
        return cls(EvaluateConfig.from_dict(to_dict(tree.evaluate)), to_dict(tree.evaluate), filter_cfg)


@dataclass(frozen=True)
class Model:
    """A scored model: its key in ``evaluation.json`` (the file's name), its vehicle file (where its band's source
    is found), the name the report gives it, and the vehicle."""

    key: str
    file: str
    label: str
    vehicle: Vehicle


@dataclass(frozen=True)
class Given:
    """A flight as given: its path, its rows (None: not read yet), the filter stage's report and cross-fit file
    (None: filtered with the settings)."""

    path: str
    measured: pd.DataFrame | None = None
    report: NisReport | None = None
    estimates: str | None = None


@dataclass(frozen=True)
class EnvelopeCheck:
    """The training flights' envelope and, per scored flight, :func:`qr.envelope.check`'s windows outside it."""

    envelope: Envelope
    trained_on: tuple[str, ...]
    outside: Mapping[str, Outside]  # per scored flight (a path: keyed by data)


@dataclass(frozen=True)
class Evaluation:
    """The models' rollout errors on the scored flights, pooled and per flight, beside the references."""

    flights: tuple[str, ...]
    models: tuple[Model, ...]
    settings: Settings
    steps: np.ndarray  # every piece's time steps, s
    pooled: dict[str, Sums]  # per model key (the references first)
    per_flight: dict[str, dict[str, Sums]]
    split: Assignment | None  # the held-out protocol's split, where there is one
    envelope: EnvelopeCheck | None  # where the training flights are known
    bands: Bands | None  # evaluate.bands.enabled


def given(flights, reports: list | None = None, estimates: list | None = None, measured: list | None = None) \
        -> list[Given]:
    """The flights as :class:`Given` (``estimates`` count only with ``reports``, whose settings they need)."""
    return [Given(str(f), measured[k] if measured else None, reports[k] if reports else None,
                  estimates[k] if estimates and reports else None) for k, f in enumerate(flights)]


def sides(scored: list[Given], trained: list[Given] | None, split: Assignment | None, ecfg: EvaluateConfig,
          say=lambda m: None) -> tuple[list[Given], list[Given] | None, Assignment | None]:
    """(the flights to score, those the models were trained on or None, the split).  Without ``split``, a
    trajectory or speed ``evaluate.split`` selects the flights to score among ``scored`` (the held-out mode);
    the others are the training side, unless ``trained`` or ``evaluate.trained_on`` names it."""
    if split is None and ecfg.split.kind != "repeat":
        split = assign([g.path for g in scored], ecfg.split)
        if not trained and not ecfg.trained_on:
            trained = [g for g in scored if g.path in split.train]
        scored = [g for g in scored if g.path in split.test]
        say(f"evaluate.split: {split.held_out}; scoring {len(scored)} flight(s)")
    return scored, trained or (given(ecfg.trained_on) if ecfg.trained_on else None), split


def model_names(vehicles: list[str]) -> list[str]:
    """Each vehicle file's name as the models' key (its path where two names clash: :func:`qr.intake.shown`)."""
    out = shown(vehicles)
    for ref in REFERENCES:
        if ref in out:
            raise QrInputError(ref, f"a vehicle file named '{ref}' clashes with the reference model of that name",
                               "rename the file")
    if len(set(out)) < len(out):
        dup = next(v for v in out if out.count(v) > 1)
        raise QrInputError(dup, "the same vehicle file is given twice", "give each --vehicle once")
    return out


def run(pieces: list[tuple[str, list[Piece]]], models: list[Model], settings: Settings, trained: list[Piece] | None = None,
        trained_on: list[str] | None = None, split: Assignment | None = None, say=lambda m: None) -> Evaluation:
    """Score ``models`` on each scored flight's ``pieces`` ((flight, its pieces) in order); ``trained``: the pieces of
    the flights ``trained_on`` (their envelope); ``split``: recorded as given."""
    ecfg = settings.evaluate
    H, gap = ecfg.horizon, ecfg.max_input_gap
    specs = {"hold": "hold", "rate_frozen": ("rate_frozen", models[0].vehicle),
             **{m.key: (m.vehicle, list(m.vehicle.effects)) for m in models}}
    envelope = Envelope.of([rollout.windows(st, ms, H, gap, keep) for st, ms, keep in trained], H) \
        if trained is not None else None
    bandset = BandSet([m.key for m in models], [m.file for m in models], [m.vehicle for m in models],
                      ecfg.bands.draws, ecfg.bands.seed, say) if ecfg.bands.enabled else None
    per_flight, steps, outside = {}, [], {}
    for f, ps in pieces:
        parts, wins = [], []
        for st, ms, keep in ps:
            steps.append(np.diff(st["t"].to_numpy(float)))
            say(f"rolling out {len(specs)} models over {int(keep.sum())} starts, H = {H}")
            parts.append(rollout.score(st, ms, H, gap, specs, keep))
            if envelope is not None or bandset is not None:
                wins.append(rollout.windows(st, ms, H, gap, keep))
            if bandset is not None:
                bandset.add(f, wins[-1], H)
        per_flight[f] = rollout.pool(parts)
        if envelope is not None:
            outside[f] = check(envelope, wins, H)
    return Evaluation(tuple(f for f, _ in pieces), tuple(models), settings, np.concatenate(steps),
                      rollout.pool(list(per_flight.values())), per_flight, split,
                      EnvelopeCheck(envelope, tuple(trained_on or ()), outside) if envelope is not None else None,
                      bandset.result() if bandset is not None else None)
