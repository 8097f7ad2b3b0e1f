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
from ..rollout import REFERENCES, EvaluateConfig
from ..errors import QrInputError
from ..holdout import held_out
from ..pieces import estimated_pieces

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
                   estimates: list | None = None, labels: list[str] | None = None, trained_on: dict | None = None,
                   split=None) -> dict:
    """Evaluate ``vehicles`` on ``flights``; write ``out`` (checked before any work).

    ``labels``: the name each vehicle's model has in the report, the figure and the tracked metrics
    (``evaluation.json``'s ``labels``; default: its key, the file's name).

    ``reports``: the filter stage's report of each flight (its tuned noise values are reused instead
    of tuning again, as ``qr diagnose`` does).  ``track``: the name of an MLflow run (experiment
    ``qr-evaluate``) to log it as (none: not tracked).  ``estimates``: the filter stage's cross-fit file
    of each flight (with ``reports``): a segment's estimate is read from it where it matches (its
    position, velocity, attitude and rate do not depend on the rotor filter's matching).

    ``trained_on``: the flights the models were trained on (``{"flights", "reports", "estimates"}``, the
    latter two as above; default ``evaluate.trained_on``): every window is checked against their envelope
    (:mod:`qr.envelope`; ``evaluation.json``'s block ``envelope``).  ``split``: the held-out protocol's
    :class:`qr.holdout.Assignment` (``evaluation.json``'s block ``split``).  Without it, a trajectory or
    speed ``evaluate.split`` selects the flights to score among ``flights`` (the held-out mode); the others
    are the training side, whose envelope the windows are checked against (unless ``evaluate.trained_on``
    names the training flights)."""
    from ..outputs import check_out_dir

    given = [str(f) for f in (trained_on or {}).get("flights", [])]
    out = check_out_dir(out, inputs=[*flights, *vehicles, *given], force=force, expected=OUTPUTS)
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
    if split is None and ecfg.split.kind != "repeat":
        # the held-out mode: the flights the split scores are evaluated, the others are the training side
        from ..holdout import assign

        split = assign([str(f) for f in flights], ecfg.split)
        keep = [k for k, f in enumerate(flights) if str(f) in split.test]
        pick = lambda xs: [xs[k] for k in keep] if xs else xs  # noqa: E731
        if not trained_on and not ecfg.trained_on:
            train = [k for k, f in enumerate(flights) if str(f) in split.train]
            trained_on = {"flights": [str(flights[k]) for k in train],
                          "reports": [reports[k] for k in train] if reports else None,
                          "estimates": [estimates[k] for k in train] if estimates else None}
        flights, measured, reports, estimates = pick(list(flights)), pick(measured), pick(reports), pick(estimates)
        say(f"evaluate.split: {split.held_out}; scoring {len(flights)} flight(s)")
    trained_on = trained_on or ({"flights": ecfg.trained_on} if ecfg.trained_on else None)
    envelope = training_envelope(trained_on, vehs[0], ecfg, filter_cfg, say) if trained_on else None
    per_flight, steps, outside = {}, [], {}
    bandset = None
    if ecfg.bands.enabled:
        from ..bands import BandSet

        bandset = BandSet(names, [str(v) for v in vehicles], vehs, ecfg.bands.draws, ecfg.bands.seed, say)
    for i, (f, m) in enumerate(zip(flights, measured)):
        conventions.require(m, vehs[0], f, ecfg.skip_checks, "evaluate.skip_checks=[{name}] at the end of the command",
                            vehicles[0])
        parts, wins = [], []
        for st, meas, keep in estimated_pieces(f, m, vehs[0], ecfg, filter_cfg, reports[i] if reports else None,
                                               estimates[i] if estimates and reports else None, say):
            steps.append(np.diff(st["t"].to_numpy(float)))
            say(f"rolling out {len(models)} models over {int(keep.sum())} starts, H = {ecfg.horizon}")
            parts.append(rollout.score(st, meas, ecfg.horizon, ecfg.max_input_gap, models, keep))
            if envelope is not None or bandset is not None:
                wins.append(rollout.windows(st, meas, ecfg.horizon, ecfg.max_input_gap, keep))
            if bandset is not None:
                bandset.add(str(f), wins[-1], ecfg.horizon)
        per_flight[str(f)] = rollout.pool(parts)
        if envelope is not None:
            from ..envelope import check

            outside[str(f)] = check(envelope, wins, ecfg.horizon)
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
    if split is not None:
        doc["split"] = split.to_dict()
    if envelope is not None:
        doc["envelope"] = envelope_block(envelope, trained_on["flights"], outside)
    if bandset is not None:
        doc["bands"], doc["bands_none"] = bandset.blocks(ecfg.horizon)
    from ..report.evaluation import mae_figure, report

    with atomic_dir(out, force=force, command="qr evaluate") as tmp:
        band_fig = None
        if figures:
            (tmp / "figures").mkdir()
            mae_figure(doc, tmp / "figures" / "rollout_mae.png")
            if doc.get("bands"):
                from ..report.bands import bands_figure

                band_fig = "figures/bands.png"
                bands_figure(doc, bandset, tmp / band_fig)
        write_text(tmp / "report.md", report(doc, "figures/rollout_mae.png" if figures else None, band_fig))
        write_json(tmp / "evaluation.json", doc)
    if track:
        from ..shipped import vehicle_file

        track_evaluation(track, doc, [*flights, *map(vehicle_file, vehicles)], out)  # (a vehicle by name: its file)
    say(f"wrote {out}/evaluation.json")
    return doc


def training_envelope(trained_on: dict, vehicle, ecfg: EvaluateConfig, filter_cfg: dict, say=lambda m: None):
    """The :class:`qr.envelope.Envelope` of the training flights (``{"flights", "reports", "estimates"}``),
    from the same windows the protocol scores."""
    from ..envelope import Envelope
    from ..flight import read_flight

    flights, reports, stored = trained_on["flights"], trained_on.get("reports"), trained_on.get("estimates")
    wins = []
    for i, f in enumerate(flights):
        for st, meas, keep in estimated_pieces(f, read_flight(f), vehicle, ecfg, filter_cfg,
                                               reports[i] if reports else None,
                                               stored[i] if stored and reports else None, say):
            wins.append(rollout.windows(st, meas, ecfg.horizon, ecfg.max_input_gap, keep))
    return Envelope.of(wins, ecfg.horizon)


def envelope_block(envelope, trained: list, outside: dict) -> dict:
    """``evaluation.json``'s ``envelope``: the training flights' extremes, and per scored flight and pooled
    the windows outside them."""
    from ..envelope import QUANTITIES

    n = sum(o["windows"] for o in outside.values())
    k = {q: sum(o["share_outside_by"][q] * o["windows"] for o in outside.values() if o["windows"]) for q in QUANTITIES}
    m = sum(o["outside"] for o in outside.values())
    return {"trained_on": [str(f) for f in trained], "limits": envelope.to_dict(), "windows": n, "outside": m,
            "share_outside": m / n if n else None,
            "share_outside_by": {q: (round(k[q]) / n if n else None) for q in QUANTITIES},
            "per_flight": outside}


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


def evaluate_held_out(flights, nis_files, vehicle, diag_out, eval_out, overrides=(), single_overrides=(),
                      track: str | None = None, estimates=None, split=None) -> dict:
    """The workflow's rollout yardstick: diagnose the training flights, evaluate the nominal and the
    extended vehicle on the held-out ones (with ``single_overrides`` instead of ``overrides`` when one
    flight trains: a lone flight's settings, as the workflow's per-flight diagnoses use).  ``split``: which
    flights are held out (:func:`held_out`); each scored window is checked against the training flights'
    envelope (:mod:`qr.envelope`)."""
    import json

    from .diagnose import run_diagnosis

    if len(flights) < 2:
        raise QrInputError(flights[0] if flights else None, "one flight cannot be held out by flight",
                           "give two flights or more")
    flights = [str(f) for f in flights]
    a = held_out(flights, split)
    train, test = list(a.train), list(a.test)
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
                          track=track, estimates=[stored[f] for f in test] if stored else None, labels=labels,
                          trained_on=_trained(a, reports, stored), split=a)


def _trained(a, reports: dict, stored: dict) -> dict:
    """The training side of an assignment as :func:`run_evaluation` takes it (its envelope)."""
    return {"flights": list(a.train), "reports": [reports[f] for f in a.train],
            "estimates": [stored[f] for f in a.train] if stored else None}


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
        from ..bands import SUFFIX, parameter_block

        band = parameter_block(doc["refine"])  # its Monte Carlo band's source, beside it (qr.bands)
        if band is not None:
            from ..atomic import write_json

            write_json(out_dir / f"refined_physical{SUFFIX}", band)
    if remainder:  # the remainder was fitted against the equation-error model
        add({**one, "effects": one_step, "torque_remainder": remainder}, "extended_vehicle.yaml", "hybrid")
    return models, labels


def evaluate_learned(flights, nis_files, vehicle, vehicles, labels, eval_out, track: str | None = None,
                     estimates=None, split=None) -> dict:
    """``vehicles`` (labelled ``labels``) on the flights the held-out protocol holds out under ``split``
    (:func:`held_out`), beside the nominal ``vehicle`` and the references: the workflow's rollout-trained
    residuals, scored on the same flights as :func:`evaluate_held_out`'s models."""
    import json

    flights = [str(f) for f in flights]
    a = held_out(flights, split)
    test = list(a.test)
    reports = dict(zip(flights, [json.loads(Path(p).read_text()) for p in nis_files]))
    stored = dict(zip(flights, estimates)) if estimates else {}
    return run_evaluation(test, [vehicle, *vehicles], eval_out, log=lambda m: None,
                          reports=[reports[f] for f in test], track=track,
                          estimates=[stored[f] for f in test] if stored else None, labels=["nominal", *labels],
                          trained_on=_trained(a, reports, stored), split=a)


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
