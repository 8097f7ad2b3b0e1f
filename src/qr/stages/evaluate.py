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
from ..rollout import EvaluateConfig, pieces, table
from ..errors import QrInputError

OUTPUTS = ("evaluation.json", "report.md", "figures/")
REFERENCES = ("hold", "rate_frozen")
# the public nanodrone-sysid-benchmark at h = 50 on its own held-out Crazyflie flights (its table)
PUBLISHED_H50 = {"physics, no drag, rate frozen": {"p": 0.127, "v": 0.578, "R": 0.254, "w": 0.884},
                 "physics + MLP residual": {"p": 0.112, "v": 0.556, "R": 0.231, "w": 0.598}}
UNITS = {"p": "m", "v": "m/s", "R": "rad", "w": "rad/s"}


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
                   estimates: list | None = None) -> dict:
    """Evaluate ``vehicles`` on ``flights``; write ``out`` (checked before any work).

    ``reports``: the filter stage's report of each flight (its tuned noise values are reused instead
    of tuning again, as ``qr diagnose`` does).  ``track``: the name of an MLflow run (experiment
    ``qr-evaluate``) to log it as (none: not tracked).  ``estimates``: the filter stage's cross-fit file
    of each flight (with ``reports``): a segment's estimate is read from it where it matches (its
    position, velocity, attitude and rate do not depend on the rotor filter's matching)."""
    from ..outputs import check_out_dir

    out = check_out_dir(out, inputs=[*flights, *vehicles], force=force, expected=OUTPUTS)
    from ..atomic import atomic_dir, write_json, write_text
    from ..config import to_dict
    from ..estimation.settings import resolve as resolve_filter
    from ..flight import read_flight
    from ..vehicle import load_vehicle

    say = log or (lambda msg: print(f"qr evaluate: {msg}", file=sys.stderr))
    cfg = _compose(overrides)
    ecfg = EvaluateConfig.from_dict(to_dict(cfg.evaluate))
    filter_cfg = to_dict(cfg.filter)
    resolve_filter(filter_cfg)
    names = model_names([str(v) for v in vehicles])
    vehs = [load_vehicle(v) for v in vehicles]
    models = models_of(vehs, names)
    measured = [read_flight(f) for f in flights]
    per_flight, steps = {}, []
    for i, (f, m) in enumerate(zip(flights, measured)):
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
        "models": {k: rollout.summary(*v) for k, v in pooled.items()},
        "per_flight": {f: {"models": {k: rollout.summary(*v) for k, v in p.items()}} for f, p in per_flight.items()},
    }
    with atomic_dir(out, force=force, command="qr evaluate") as tmp:
        figs = {}
        if figures:
            (tmp / "figures").mkdir()
            figs = {"MAE against the step h, per model (pooled over all windows)":
                    mae_figure(doc["models"], tmp / "figures" / "rollout_mae.png")}
        write_text(tmp / "report.md", report(doc, figs))
        write_json(tmp / "evaluation.json", doc)
    if track:
        track_evaluation(track, doc, [*flights, *vehicles], out)
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
    from ..diagnose.crossfit import Estimates, fixed_settings
    from ..estimation import estimate
    from ..segments import flight_segments

    fs = flight_segments(flight, vehicle, 2 * ecfg.trim_s + 0.5, path)
    settings = fixed_settings(filter_cfg, report) if report else filter_cfg
    stored = Estimates(stored, filter_cfg, report, vehicle) if stored is not None and report else None
    out = []
    for seg in fs.used:
        got = stored.get(seg.window[0]) if stored else None
        say(f"estimates of {Path(path).name} {seg.window[0]:.2f}-{seg.window[1]:.2f} s ({len(seg.rows)} samples): "
            + ("read from the filter stage" if got else "filtering"))
        st = got[0] if got else estimate(seg.rows, vehicle, settings)[0]
        out.append(pieces(st, seg.rows, ecfg.trim_s))
    if not out:
        raise QrInputError(path, "no airborne, gap-free segment is long enough to evaluate",
                           "give a longer flight, or a smaller evaluate.trim_s")
    return out


def track_evaluation(name: str, doc: dict, inputs, outdir) -> None:
    """One MLflow run: MAE at h = H per model and quantity, and each model's ratio to ``rate_frozen``."""
    from .. import tracking

    with tracking.run("evaluate", name, doc["config"], inputs=inputs) as run:
        run.metrics(rollout.horizon_metrics(doc["models"], doc["horizon"], ratios=True))
        run.tags({"qr.models": ",".join(doc["models"])})
        for p in ("evaluation.json", "report.md"):
            if (Path(outdir) / p).exists():
                run.artifact(Path(outdir) / p)


def report(doc: dict, figs: dict) -> str:
    H = doc["horizon"]
    lo, hi = doc["dt_range"]
    lines = [f"# Rollout evaluation ({len(doc['flights'])} flight{'s' if len(doc['flights']) > 1 else ''})", "",
             f"Open-loop rollout over H = {H} steps (dt {doc['dt'] * 1e3:.2f} ms, the log's own steps: "
             f"{lo * 1e3:.2f}-{hi * 1e3:.2f} ms), from every sample of the filtered estimate; truth: the measured "
             "position and attitude, the estimated velocity and body rate. Mean absolute error per step h: "
             "p (m), v (m/s), R (rad, rotation angle of q⁻¹ ⊗ q̂), w (rad/s); SimErr = the sum over h = 1..H.",
             "", "References: `hold` (the state held), `rate_frozen` (nominal thrust along body z, no drag, body rate "
             "held at its start value: the public nanodrone-sysid-benchmark's physics baseline).", "",
             *table(doc["models"], H), ""]
    for title, path in figs.items():
        lines += [f"![{title}](figures/{path})", ""]
    lines += ["For comparison, the benchmark's published h = 50 figures on its own held-out Crazyflie flights "
              "(other flights, so only the orders of magnitude compare):", ""]
    lines += [f"- {k}: " + ", ".join(f"{q} {v} {UNITS[q]}" for q, v in d.items()) for k, d in PUBLISHED_H50.items()]
    if len(doc["per_flight"]) > 1:
        lines += ["", "## Per flight", ""]
        for f, p in doc["per_flight"].items():
            lines += [f"### {f}", "", *table(p["models"], H), ""]
    return "\n".join(lines) + "\n"


def mae_figure(models: dict, path: Path) -> str:
    from ..report import figures

    fig, axs = figures.subplots(1, 4, figsize=(13, 3.4), layout="constrained")
    for k, q in enumerate(rollout.QUANTITIES):
        for j, (name, block) in enumerate(models.items()):
            m = np.array([np.nan if x is None else x for x in block[q]["mae"]])
            axs[k].plot(np.arange(1, len(m) + 1), m, label=name,
                        color={"hold": "0.6", "rate_frozen": "0.2"}.get(name, f"C{j}"),
                        ls="--" if name in REFERENCES else "-")
        axs[k].set_xlabel("h (steps)")
        axs[k].set_ylim(bottom=0)
        axs[k].set_title(f"{q} ({UNITS[q]})", fontsize=10)
    axs[0].set_ylabel("mean absolute error")
    axs[0].legend(fontsize=7)
    figures.save(fig, path)
    return path.name


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
    import tempfile

    from ..vehicle import load_vehicle, save_vehicle

    train, test = held_out_by_flight(flights)
    reports = dict(zip(flights, [json.loads(Path(p).read_text()) for p in nis_files]))
    if len(train) == 1 and single_overrides:
        overrides = single_overrides
    stored = dict(zip(flights, estimates)) if estimates else {}
    run_diagnosis(train, vehicle, diag_out, list(overrides), track=False, figures=False,
                  reports=[reports[f] for f in train], log=lambda m: None,
                  estimates=[stored[f] for f in train] if stored else None)
    ext = Path(diag_out) / "extended_vehicle.yaml"
    models = [vehicle, str(ext)]
    with tempfile.TemporaryDirectory() as tmp:
        if load_vehicle(ext).raw.get("torque_remainder"):  # a hybrid: its physical part beside it
            physical = load_vehicle(ext).to_dict()
            physical.pop("torque_remainder")
            save_vehicle(physical, Path(tmp) / "extended_physical.yaml")
            models.insert(1, str(Path(tmp) / "extended_physical.yaml"))
        return run_evaluation(test, models, eval_out, log=lambda m: None, reports=[reports[f] for f in test],
                              track=track, estimates=[stored[f] for f in test] if stored else None)


def summary_table(eval_dirs: dict, table) -> pd.DataFrame:
    """The held-out rollouts of the flight sets side by side: MAE at h = H and the ratio to ``rate_frozen``."""
    import json

    from ..report.tables import write_table

    rows = []
    for name, d in eval_dirs.items():
        doc = json.loads((Path(d) / "evaluation.json").read_text())
        H, models = doc["horizon"], doc["models"]
        base = models["rate_frozen"]
        names = list(models)[2:]
        labels = dict(zip(names, ["nominal", "extended"] if len(names) == 2 else ["nominal", "extended", "hybrid"]))
        for model, block in models.items():
            row = {"set": name, "held-out flights": len(doc["flights"]), "model": labels.get(model, model)}
            for q in rollout.QUANTITIES:
                x, b = rollout.at(block, H, q), rollout.at(base, H, q)
                row[f"{q}@{H}"] = x
                row[f"{q} / rate_frozen"] = None if x is None or not b else x / b
            rows.append(row)
    df = pd.DataFrame(rows)
    write_table(df, table, title="Rollout on held-out flights (qr evaluate; ratio < 1: better than the "
                                 "benchmark's physics baseline)")
    return df
