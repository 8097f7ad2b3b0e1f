"""Stage evaluate, the workflow's held-out rollouts (rules ``evaluate_held_out``, ``evaluate_learned``,
``evaluation_summary``, ``generalization_fold``; docs/evaluate.md, docs/workflow.md).

The held-out protocol (:func:`evaluate_held_out`): the training flights of a split are diagnosed (the
diagnose stage, its folder written as ``qr diagnose`` writes it), and the vehicles that diagnosis makes
(:meth:`qr.diagnose.diagnosis.Diagnosis.models`: nominal, extended, refined, hybrid, in memory) are rolled out
on the held-out flights, each window checked against the training flights' envelope.  A fold
(:func:`run_fold`, :class:`qr.holdout.Fold`) adds a residual trained through the rollout on the same training
flights, scored on the same held-out flights (:func:`evaluate_learned`).  :func:`summary_table`: the sets'
held-out rollouts side by side.  The commands of one job share one :class:`qr.intake.Memo`: each flight is read,
convention-checked and estimated once per job.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import pandas as pd

from ..holdout import held_out
from ..intake import Memo, read_reports
from .evaluate import run_evaluation

HELD_OUT_MODELS = "held_out_models"  # (in the training diagnosis's folder)
FOLD_SCHEMA = "qr.fold/1"
RESIDUAL_LABEL = "hybrid (rollout-trained)"


def _quiet(msg: str) -> None:
    pass


def _trained(a, reports: dict, stored: dict) -> dict:
    """The training side of an assignment as :func:`run_evaluation` takes it (its envelope)."""
    return {"flights": list(a.train), "reports": [reports[f] for f in a.train],
            "estimates": [stored[f] for f in a.train] if stored else None}


def evaluate_held_out(flights, nis_files, vehicle, diag_out, eval_out, overrides=(), single_overrides=(),
                      track: str | None = None, estimates=None, split=None, reports: dict | None = None,
                      memo: Memo | None = None) -> dict:
    """The workflow's rollout yardstick: diagnose the training flights, evaluate the nominal, extended,
    refined and hybrid vehicles on the held-out ones (with ``single_overrides`` instead of ``overrides`` when
    one flight trains: a lone flight's settings, as the workflow's per-flight diagnoses use).  ``split``:
    which flights are held out (:func:`qr.holdout.held_out`); ``reports``: flight -> its ``nis_files`` report,
    already read; ``memo``: what the job took already (default: a new one, shared by the diagnosis and the
    rollouts)."""
    from ..errors import QrInputError
    from .diagnose import run_diagnosis

    if len(flights) < 2:
        raise QrInputError(flights[0] if flights else None, "one flight cannot be held out by flight",
                           "give two flights or more")
    flights = [str(f) for f in flights]
    a = held_out(flights, split)
    train, test = list(a.train), list(a.test)
    reports = reports or dict(zip(flights, read_reports(nis_files)))
    if len(train) == 1 and single_overrides:
        overrides = single_overrides
    stored = dict(zip(flights, estimates)) if estimates else {}
    memo = memo or Memo()
    doc, diagnosis = run_diagnosis(train, vehicle, diag_out, list(overrides), track=False, figures=False,
                                   reports=[reports[f] for f in train], log=_quiet, return_result=True,
                                   estimates=[stored[f] for f in train] if stored else None, memo=memo)
    files, vehicles, labels = held_out_models(vehicle, diagnosis, doc, Path(diag_out) / HELD_OUT_MODELS)
    return run_evaluation(test, files, eval_out, log=_quiet, reports=[reports[f] for f in test], track=track,
                          estimates=[stored[f] for f in test] if stored else None, labels=labels,
                          trained_on=_trained(a, reports, stored), split=a, loaded=vehicles, memo=memo)


def held_out_models(vehicle, diagnosis, doc: dict, out_dir: Path) -> tuple[list[str], list, list[str]]:
    """(the vehicle files the held-out rollout scores, their vehicles, their labels) of a training
    ``diagnosis`` (``doc``: its diagnosis.json): the nominal ``vehicle``; the extended one (the equation-error
    estimates); with ``diagnose.refine=rollout`` the refined physical model (``physical (refined)``, its
    Monte Carlo band's source beside it: :mod:`qr.bands`); with a learned torque remainder the extended
    model plus it (``hybrid``).  The compared vehicles are written to ``out_dir`` (evaluation.json names
    them; the replay flies them)."""
    from ..atomic import write_json
    from ..bands import SUFFIX, parameter_block
    from ..vehicle import save_vehicle

    m = diagnosis.models()
    out_dir.mkdir(exist_ok=True)
    files, vehicles, labels = [str(vehicle)], [m.nominal], ["nominal"]

    def add(v, name, label):
        save_vehicle(v, out_dir / name)
        files.append(str(out_dir / name))
        vehicles.append(v)
        labels.append(label)

    add(m.extended, "extended_physical.yaml" if m.hybrid else "extended_vehicle.yaml", "extended")
    if m.refined is not None:
        add(m.refined, "refined_physical.yaml", "physical (refined)")
        band = parameter_block(doc["refine"])
        if band is not None:
            write_json(out_dir / f"refined_physical{SUFFIX}", band)
    if m.hybrid is not None:  # the remainder was fitted against the equation-error model
        add(m.hybrid, "extended_vehicle.yaml", "hybrid")
    return files, vehicles, labels


def evaluate_learned(flights, nis_files, vehicle, vehicles, labels, eval_out, track: str | None = None,
                     estimates=None, split=None, reports: dict | None = None, memo: Memo | None = None) -> dict:
    """``vehicles`` (labelled ``labels``) on the flights the held-out protocol holds out under ``split``,
    beside the nominal ``vehicle`` and the references: the workflow's rollout-trained residuals, scored on
    the same flights as :func:`evaluate_held_out`'s models (``reports``, ``memo``: as there)."""
    flights = [str(f) for f in flights]
    a = held_out(flights, split)
    test = list(a.test)
    reports = reports or dict(zip(flights, read_reports(nis_files)))
    stored = dict(zip(flights, estimates)) if estimates else {}
    return run_evaluation(test, [vehicle, *vehicles], eval_out, log=_quiet,
                          reports=[reports[f] for f in test], track=track,
                          estimates=[stored[f] for f in test] if stored else None, labels=["nominal", *labels],
                          trained_on=_trained(a, reports, stored), split=a, memo=memo)


def run_fold(flights, nis_files, vehicle, out, fold, overrides=(), single_overrides=(), residual_overrides=(),
             estimates=None, track: str | None = None, log=_quiet) -> dict:
    """Train and score one held-out fold (``fold``: a :class:`qr.holdout.Fold`): the training flights
    diagnosed and the held-out ones scored (:func:`evaluate_held_out`: ``OUT/training_diagnosis/``,
    ``OUT/held_out/``), and where the fold asks for it a residual trained through the rollout on the training
    flights (validation: whole trajectories of the training side; ``residual_overrides``: ``qr learn
    residual``'s) and scored on the same flights (``OUT/residual/``, ``OUT/learned/``); ``OUT/fold.json``
    (the split and what each step took, s) last.  Returns ``fold.json``'s document.  The filter stage's reports
    are read once, and each flight read, convention-checked and estimated once, for every step (one
    :class:`qr.intake.Memo`)."""
    from ..atomic import write_json
    from .learn_residual_sets import train_held_out

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    flights = [str(f) for f in flights]
    a = held_out(flights, fold.split)
    seconds = {}
    t0 = time.perf_counter()
    reports = dict(zip(flights, read_reports(nis_files)))
    memo = Memo()
    log(f"fold {fold.name}: {a.held_out}; diagnosing {len(a.train)} flights, scoring {len(a.test)}")
    evaluate_held_out(flights, nis_files, vehicle, out / "training_diagnosis", out / "held_out", overrides,
                      single_overrides, track=track, estimates=estimates, split=fold.split, reports=reports, memo=memo)
    seconds["diagnose_and_evaluate"] = time.perf_counter() - t0
    if fold.hybrid:
        t0 = time.perf_counter()
        log(f"fold {fold.name}: training a residual through the rollout")
        train_held_out(flights, out / "training_diagnosis" / "extended_vehicle.yaml", out / "residual",
                       list(residual_overrides), reports=[reports[f] for f in flights], estimates=estimates,
                       split=fold.split, track=False, log=log, memo=memo)
        seconds["residual"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        evaluate_learned(flights, nis_files, vehicle, [out / "residual" / "hybrid_vehicle.yaml"], [RESIDUAL_LABEL],
                         out / "learned", track=f"{track}:learned" if track else None, estimates=estimates,
                         split=fold.split, reports=reports, memo=memo)
        seconds["evaluate_residual"] = time.perf_counter() - t0
    doc = {"schema": FOLD_SCHEMA, "fold": fold.to_dict(), "split": a.to_dict(), "seconds": seconds,
           "evaluations": ["held_out"] + (["learned"] if fold.hybrid else [])}
    write_json(out / "fold.json", doc)
    return doc


def summary_table(eval_dirs: dict, table) -> pd.DataFrame:
    """The held-out rollouts of the flight sets side by side: MAE at h = H and the ratio to ``rate_frozen``
    (a set's value: its evaluation folder, or several on the same flights, whose models are added in order,
    each model and reference once)."""
    from ..evaluate.report import labels
    from ..report.tables import write_table

    rows = []
    for name, dirs in eval_dirs.items():
        seen = set()
        for d in [dirs] if isinstance(dirs, (str, Path)) else dirs:
            rows += _summary_rows(name, json.loads((Path(d) / "evaluation.json").read_text()), labels, seen)
    df = pd.DataFrame(rows)
    write_table(df, table, title="Rollout on held-out flights (qr evaluate; ratio < 1: better than the "
                                 "benchmark's physics baseline)")
    return df


def _summary_rows(name: str, doc: dict, labels, seen: set) -> list[dict]:
    """One row per model of one evaluation not already in ``seen`` (labels)."""
    from ..evaluate.report import ratio
    from ..rollout import QUANTITIES, at

    H, models, label = doc["horizon"], doc["models"], labels(doc)
    rows = []
    for model, block in models.items():
        if label[model] in seen:
            continue
        seen.add(label[model])
        row = {"set": name, "held-out flights": len(doc["flights"]), "model": label[model],
               "horizon (s)": round(H * doc["dt"], 6)}
        for q in QUANTITIES:
            row[f"{q}@{H}"] = at(block, H, q)
            row[f"{q} / rate_frozen"] = ratio(models, model, q, H)
        rows.append(row)
    return rows
