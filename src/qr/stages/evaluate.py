"""``qr evaluate``: score vehicle models by multi-step open-loop rollout (docs/spec/evaluate.md).

Each flight is split like ``qr diagnose`` splits it (airborne, gap-free segments), filtered
(``evaluate.filter``), and every sample of each segment (less ``trim_s`` at both ends) starts a
window (:mod:`qr.rollout`).  Writes ``OUTDIR/evaluation.json``, ``report.md`` and
``figures/rollout_mae.png``, all at once, after checking where they go.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from .. import rollout
from ..rollout import REFERENCES, EvaluateConfig, pieces
from ..errors import QrInputError

OUTPUTS = ("evaluation.json", "report.md", "figures/")


def _compose(overrides):
    from ..config import compose_stage

    return compose_stage(overrides, "evaluate", "evaluate.horizon=100")


def model_names(vehicles: list[str]) -> list[str]:
    """Each vehicle file's name as the models' key (its path where two names clash)."""
    names = [Path(v).name for v in vehicles]
    out = [str(v) if names.count(n) > 1 else n for v, n in zip(vehicles, names)]
    for ref in REFERENCES:
        if ref in out:
            raise QrInputError(ref, f"a vehicle file named '{ref}' clashes with the reference model of that name",
                               "rename the file")
    if len(set(out)) < len(out):
        dup = next(v for v in out if out.count(v) > 1)
        raise QrInputError(dup, "the same vehicle file is given twice", "give each --vehicle once")
    return out


def models_of(vehicles: list, names: list[str]) -> dict:
    """The models :func:`qr.rollout.score` runs: the references (on the first vehicle) and each vehicle."""
    models = {"hold": "hold", "rate_frozen": ("rate_frozen", vehicles[0])}
    for name, v in zip(names, vehicles):
        models[name] = (v, list(v.effects))
    return models


def run_evaluation(flights, vehicles, out, overrides=(), force: bool = False, log=None,
                   figures: bool = True, reports: list | None = None, track: str | None = None,
                   estimates: list | None = None, labels: list[str] | None = None) -> dict:
    """Evaluate ``vehicles`` on ``flights``; write ``out`` (checked before any work).

    ``labels``: the name each vehicle's model has in the report, the figure and the tracked metrics
    (``evaluation.json``'s ``labels``; default: its key, the file's name).

    ``reports``: the filter stage's report of each flight (its tuned noise values are reused instead
    of tuning again, as ``qr diagnose`` does).  ``track``: the name of an MLflow run (experiment
    ``qr-evaluate``) to log it as (none: not tracked).  ``estimates``: the filter stage's cross-fit file
    of each flight (with ``reports``): a segment's estimate is read from it where it matches (its
    position, velocity, attitude and rate do not depend on the rotor filter's matching)."""
    from ..outputs import check_out_dir

    out = check_out_dir(out, inputs=[*flights, *vehicles], force=force, expected=OUTPUTS)
    from ..flight import read_flight
    from ..vehicle import load_vehicle

    # the inputs first: a file that is missing or wrong is refused before the heavy imports and Hydra
    names = model_names([str(v) for v in vehicles])
    vehs = [load_vehicle(v) for v in vehicles]
    measured = [read_flight(f) for f in flights]

    from .. import conventions
    from ..atomic import atomic_dir, write_json, write_text
    from ..config import to_dict
    from ..estimation.settings import resolve as resolve_filter

    say = log or (lambda msg: print(f"qr evaluate: {msg}", file=sys.stderr))
    cfg = _compose(overrides)
    ecfg = EvaluateConfig.from_dict(to_dict(cfg.evaluate))
    filter_cfg = to_dict(cfg.filter)
    resolve_filter(filter_cfg)
    models = models_of(vehs, names)
    per_flight, steps = {}, []
    for i, (f, m) in enumerate(zip(flights, measured)):
        conventions.require(m, vehs[0], f, ecfg.skip_checks, "evaluate.skip_checks=[{name}] at the end of the command",
                            vehicles[0])
        parts = []
        for st, meas, keep in estimated_pieces(f, m, vehs[0], ecfg, filter_cfg, reports[i] if reports else None,
                                               estimates[i] if estimates and reports else None, say):
            steps.append(np.diff(st["t"].to_numpy(float)))
            say(f"rolling out {len(models)} models over {int(keep.sum())} starts, H = {ecfg.horizon}")
            parts.append(rollout.score(st, meas, ecfg.horizon, ecfg.max_input_gap, models, keep))
        per_flight[str(f)] = rollout.pool(parts)
    pooled = rollout.pool(list(per_flight.values()))
    dt = np.concatenate(steps)
    doc = {
        "schema": "qr.evaluation/1",
        "flights": [str(f) for f in flights],
        "vehicles": [str(v) for v in vehicles],
        "dt": float(np.median(dt)),
        "dt_range": [float(dt.min()), float(dt.max())],
        "horizon": ecfg.horizon,
        "config": {"evaluate": {**to_dict(cfg.evaluate)}, "filter": filter_cfg},
        "labels": dict(zip(names, labels or names)),
        "models": {k: rollout.summary(*v) for k, v in pooled.items()},
        "per_flight": {f: {"models": {k: rollout.summary(*v) for k, v in p.items()}} for f, p in per_flight.items()},
    }
    from ..report.evaluation import mae_figure, report

    with atomic_dir(out, force=force, command="qr evaluate") as tmp:
        if figures:
            (tmp / "figures").mkdir()
            mae_figure(doc, tmp / "figures" / "rollout_mae.png")
        write_text(tmp / "report.md", report(doc, "figures/rollout_mae.png" if figures else None))
        write_json(tmp / "evaluation.json", doc)
    if track:
        from ..shipped import vehicle_file

        track_evaluation(track, doc, [*flights, *map(vehicle_file, vehicles)], out)  # (a vehicle by name: its file)
    say(f"wrote {out}/evaluation.json")
    return doc


def estimated_pieces(path, flight: pd.DataFrame, vehicle, ecfg: EvaluateConfig, filter_cfg: dict,
                     report: dict | None = None, stored=None, say=lambda msg: None) -> list:
    """The evaluate protocol's pieces of one flight: ``(states, measured, keep)`` per airborne, gap-free
    segment (:func:`qr.rollout.pieces`), the start states from the filter stage's estimate.

    Split like ``qr diagnose`` splits a flight; each segment filtered with ``filter_cfg`` (the tuned noise
    values of the filter stage's ``report`` frozen, when given) or, with ``stored`` (the filter stage's
    cross-fit file, with ``report``), its estimate read from there where it matches.  The one path by
    which ``qr evaluate`` and ``qr learn residual`` get their windows."""
    from ..estimation.crossfit import Estimates, fixed_settings
    from ..estimation import estimate
    from ..segments import flight_segments

    fs = flight_segments(flight, vehicle, 2 * ecfg.trim_s + 0.5, path)
    settings = fixed_settings(filter_cfg, report) if report else filter_cfg
    stored = Estimates(stored, filter_cfg, report, vehicle) if stored is not None and report else None
    out = []
    for seg in fs.used:
        got = stored.get(seg.window[0]) if stored else None
        say(f"estimates of {path} {seg.window[0]:.2f}-{seg.window[1]:.2f} s ({len(seg.rows)} samples): "
            + ("read from the filter stage" if got else "filtering"))
        st = got[0] if got else estimate(seg.rows, vehicle, settings)[0]
        out.append(pieces(st, seg.rows, ecfg.trim_s))
    if not out:
        raise QrInputError(path, "no airborne, gap-free segment is long enough to evaluate",
                           "give a longer flight, or a smaller evaluate.trim_s")
    return out


def track_evaluation(name: str, doc: dict, inputs, outdir) -> None:
    """One MLflow run: MAE at h = H per model and quantity, and each model's ratio to ``rate_frozen``
    (metrics named by the models' labels), the report's first sentence as the run's description."""
    import re

    from .. import tracking
    from ..report.evaluation import headline, labels

    # a label as an MLflow metric name ("physical (refined)" -> physical_refined): no parentheses or commas
    name_of = {k: re.sub(r"[^A-Za-z0-9_\-./:]+", "_", v).strip("_") for k, v in labels(doc).items()}
    with tracking.run("evaluate", name, doc["config"], inputs=inputs, description=headline(doc)) as run:
        run.metrics(rollout.horizon_metrics({name_of[k]: v for k, v in doc["models"].items()}, doc["horizon"],
                                            ratios=True))
        run.tags({"qr.models": ",".join(name_of.values())})
        for p in ("evaluation.json", "report.md"):
            if (Path(outdir) / p).exists():
                run.artifact(Path(outdir) / p)


def held_out_by_flight(flights: list[str]) -> tuple[list[str], list[str]]:
    """(training, held-out) flights: every third flight held out (the last one of fewer than three)."""
    flights = list(flights)
    test = flights[2::3] if len(flights) >= 3 else flights[-1:]
    return [f for f in flights if f not in test], test


def evaluate_held_out(flights, nis_files, vehicle, diag_out, eval_out, overrides=(), single_overrides=(),
                      track: str | None = None, estimates=None) -> dict:
    """The workflow's rollout yardstick: diagnose the training flights, evaluate the nominal and the
    extended vehicle on the held-out ones (with ``single_overrides`` instead of ``overrides`` when one
    flight trains: a lone flight's settings, as the workflow's per-flight diagnoses use)."""
    import json

    from .diagnose import run_diagnosis

    if len(flights) < 2:
        raise QrInputError(flights[0] if flights else None, "one flight cannot be held out by flight",
                           "give two flights or more")
    train, test = held_out_by_flight(flights)
    reports = dict(zip(flights, [json.loads(Path(p).read_text()) for p in nis_files]))
    if len(train) == 1 and single_overrides:
        overrides = single_overrides
    stored = dict(zip(flights, estimates)) if estimates else {}
    run_diagnosis(train, vehicle, diag_out, list(overrides), track=False, figures=False,
                  reports=[reports[f] for f in train], log=lambda m: None,
                  estimates=[stored[f] for f in train] if stored else None)
    # the compared vehicle files stay beside the training diagnosis they come from: evaluation.json names them
    models_dir = Path(diag_out) / HELD_OUT_MODELS
    models_dir.mkdir(exist_ok=True)
    models, labels = held_out_models(vehicle, diag_out, models_dir)
    return run_evaluation(test, models, eval_out, log=lambda m: None, reports=[reports[f] for f in test],
                          track=track, estimates=[stored[f] for f in test] if stored else None, labels=labels)


HELD_OUT_MODELS = "held_out_models"  # (in the training diagnosis's folder)


def held_out_models(vehicle, diag_out, out_dir: Path) -> tuple[list[str], list[str]]:
    """The vehicle files the held-out rollout scores, and their labels, from a training diagnosis in
    ``diag_out``: the nominal vehicle; the extended one (the equation-error estimates); with
    ``diagnose.refine=rollout`` the refined physical model (``physical (refined)``); with a learned torque
    remainder the equation-error model plus it (``hybrid``).  Those not written as such are written to
    ``out_dir``."""
    import json

    from ..vehicle import load_vehicle, save_vehicle

    ext = load_vehicle(Path(diag_out) / "extended_vehicle.yaml")
    doc = json.loads((Path(diag_out) / "diagnosis.json").read_text())
    base = load_vehicle(vehicle)
    one_step = base.effects + [{"name": e["name"], "parameters": e["parameters"]} for e in doc["effects"]]
    models, labels = [str(vehicle)], ["nominal"]

    def add(raw, name, label):
        save_vehicle(raw, out_dir / name)
        models.append(str(out_dir / name))
        labels.append(label)

    raw = ext.to_dict()
    remainder = raw.pop("torque_remainder", None)
    # the one-step model: the equation-error effects on the nominal vehicle's own rotor properties (the
    # refinement may have written others)
    from ..vehicle import ROTOR_PROPERTIES

    one = {k: v for k, v in raw.items() if k not in ROTOR_PROPERTIES}
    one.update({k: base.raw[k] for k in ROTOR_PROPERTIES if k in base.raw})
    add({**one, "effects": one_step}, "extended_physical.yaml" if remainder else "extended_vehicle.yaml", "extended")
    if doc.get("refine"):
        add(raw, "refined_physical.yaml", "physical (refined)")
    if remainder:  # the remainder was fitted against the equation-error model
        add({**one, "effects": one_step, "torque_remainder": remainder}, "extended_vehicle.yaml", "hybrid")
    return models, labels


def evaluate_learned(flights, nis_files, vehicle, vehicles, labels, eval_out, track: str | None = None,
                     estimates=None) -> dict:
    """``vehicles`` (labelled ``labels``) on the flights the held-out protocol holds out
    (:func:`held_out_by_flight`), beside the nominal ``vehicle`` and the references: the workflow's
    rollout-trained residuals, scored on the same flights as :func:`evaluate_held_out`'s models."""
    import json

    _, test = held_out_by_flight(flights)
    reports = dict(zip(flights, [json.loads(Path(p).read_text()) for p in nis_files]))
    stored = dict(zip(flights, estimates)) if estimates else {}
    return run_evaluation(test, [vehicle, *vehicles], eval_out, log=lambda m: None,
                          reports=[reports[f] for f in test], track=track,
                          estimates=[stored[f] for f in test] if stored else None, labels=["nominal", *labels])


def summary_table(eval_dirs: dict, table) -> pd.DataFrame:
    """The held-out rollouts of the flight sets side by side: MAE at h = H and the ratio to ``rate_frozen``
    (a set's value: its evaluation folder, or several on the same flights, whose models are added in order,
    each model and reference once)."""
    import json

    from ..report.evaluation import labels, ratio
    from ..report.tables import write_table

    rows = []
    for name, dirs in eval_dirs.items():
        seen = set()
        for d in [dirs] if isinstance(dirs, (str, Path)) else dirs:
            doc = json.loads((Path(d) / "evaluation.json").read_text())
            H, models, label = doc["horizon"], doc["models"], labels(doc)
            rows += _summary_rows(name, doc, H, models, label, seen, ratio)
    df = pd.DataFrame(rows)
    write_table(df, table, title="Rollout on held-out flights (qr evaluate; ratio < 1: better than the "
                                 "benchmark's physics baseline)")
    return df


def _summary_rows(name, doc, H, models, label, seen, ratio) -> list[dict]:
    """One row per model of one evaluation not already in ``seen`` (labels)."""
    rows = []
    for model, block in models.items():
        if label[model] in seen:
            continue
        seen.add(label[model])
        row = {"set": name, "held-out flights": len(doc["flights"]), "model": label[model],
               "horizon (s)": round(H * doc["dt"], 6)}
        for q in rollout.QUANTITIES:
            row[f"{q}@{H}"] = rollout.at(block, H, q)
            row[f"{q} / rate_frozen"] = ratio(models, model, q, H)
        rows.append(row)
    return rows
