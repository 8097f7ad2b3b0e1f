"""``qr diagnose``: show what the nominal model gets wrong, name the cause, extend the model, measure the gain.

Contract: ../shared/spec/diagnosis.md.  ``run_diagnosis`` reads the flights and
the vehicle, filters (zero-lag smoother by default), diagnoses (``core``) and
writes ``OUTDIR/diagnosis.json``, ``report.md``, ``figures/`` and
``extended_vehicle.yaml``, all at once (a temporary directory renamed into
place) and nothing anywhere else.
"""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import QrInputError


def _compose(overrides):
    from ..config import compose

    overrides = list(overrides)
    try:
        cfg = compose(overrides)
        if not any(o.split("=")[0].lstrip("+~") == "filter" for o in overrides):
            cfg = compose(overrides + [f"filter={cfg.diagnose.filter}"])
    except Exception as e:  # Hydra's errors are long; the first line says what is wrong
        raise QrInputError("overrides", str(e).strip().splitlines()[0],
                           "use KEY=VALUE for keys in conf/ (e.g. diagnose.horizon_s=2, filter=auto)") from None
    return cfg


def prepare_flight(flight, vehicle, filter_cfg: dict, report: dict | None = None):
    """Filtered states for the diagnosis and the cross-fitting halves of one canonical flight.

    ``report``: the filter stage's report of this flight (its tuned noise values are
    reused instead of tuning again).  Returns ``(states, (even, odd), report)``.
    """
    from ..estimation import estimate
    from .crossfit import halves, matched_settings
    from .matched import add_matched_rotor_signals

    if report is None:
        _, report = estimate(flight, vehicle, filter_cfg)
    matched = matched_settings(filter_cfg, report)
    st, _ = estimate(flight, vehicle, matched)
    return add_matched_rotor_signals(st, flight, matched), halves(flight, vehicle, matched), report


def run_diagnosis(flights, vehicle, out, overrides=(), track: bool | None = None, log=None,
                  return_result: bool = False, reports: list | None = None, figures: bool = True):
    from ..atomic import atomic_dir, write_json
    from ..config import to_dict
    from ..estimation.settings import resolve as resolve_filter
    from ..flight import read_flight
    from ..vehicle import load_vehicle, save_vehicle
    from .core import DiagnoseConfig, diagnose, extended_effects
    from .report import make_figures, to_json, write_report

    say = log or (lambda msg: print(f"qr diagnose: {msg}", file=sys.stderr))
    cfg = _compose(overrides)
    dcfg_dict = to_dict(cfg.diagnose)
    dcfg = DiagnoseConfig.from_dict(dcfg_dict)
    resolve_filter(to_dict(cfg.filter))  # the filter settings too, before any work
    vehicle = load_vehicle(vehicle)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise QrInputError(out, "output path exists and is not a directory", "give a directory for --out")
    measured = [read_flight(f, vehicle) for f in flights]
    # the training part of a lone flight must hold a block per cross-validation fold
    blocks = dcfg.selection.folds if len(flights) == 1 else 1
    need = 2 * dcfg.trim_s + (blocks * dcfg.block_s + dcfg.gap_s / 2) / dcfg.train_fraction
    for f, m in zip(flights, measured):
        span = m["t"].iloc[-1] - m["t"].iloc[0]
        if span < need:
            raise QrInputError(f, f"flight lasts {span:.1f} s, too short to hold out a test part (needs {need:.1f} s)",
                               "give a longer flight (30 s or more), several flights, or a smaller diagnose.block_s")
    states, pairs = [], []
    for i, m in enumerate(measured):
        say(f"filtering {Path(flights[i]).name} ({len(m)} samples, filter={cfg.filter.get('name', '?')})")
        st, pair, _ = prepare_flight(m, vehicle, to_dict(cfg.filter), reports[i] if reports else None)
        states.append(st)
        pairs.append(pair)
    say("identifying effects")
    res = diagnose(states, measured, vehicle, dcfg, seed=int(cfg.seed), progress=lambda s: say(s), pairs=pairs)
    from .remainder import remainder

    say("checking for structure beyond the catalog")
    res["remainder"] = remainder(res, vehicle, dcfg)
    doc = to_json(res, [Path(f).name for f in flights], dcfg_dict)
    doc["filter"] = to_dict(cfg.filter)
    ext = vehicle.with_changes(effects=vehicle.effects + extended_effects(res["effects"]))
    with atomic_dir(out) as tmp:
        figs = make_figures(tmp, res, vehicle) if figures else {}
        write_report(tmp, doc, res, figs)
        write_json(tmp / "diagnosis.json", doc)
        save_vehicle(ext, tmp / "extended_vehicle.yaml",
                     header=f"Extended vehicle from qr diagnose of {', '.join(doc['flights'])}: "
                            "the nominal parameters plus the named effects")
    if track if track is not None else bool(cfg.diagnose.get("track", False)):
        track_diagnosis(out.name, doc, flights, out, {"nominal_loss": res["nominal_loss"],
                                                      "extended_loss": res["extended_loss"]})
    say(doc["verdict"])
    return (doc, res) if return_result else doc


def track_diagnosis(name, doc: dict, inputs, outdir, metrics: dict | None = None) -> None:
    """One MLflow run (experiment ``qr-diagnose``) for a written diagnosis in ``outdir``."""
    from .. import tracking

    outdir = Path(outdir)
    with tracking.run("diagnose", name, {"diagnose": doc["config"], "filter": doc.get("filter", {})},
                      inputs=inputs) as run:
        run.metrics({**(metrics or {}), "effects_named": len(doc["effects"]),
                     "replay.nominal_position_rmse": doc["replay"]["nominal_position_rmse"],
                     "replay.extended_position_rmse": doc["replay"]["extended_position_rmse"]})
        run.tags({"qr.effects": ",".join(e["name"] for e in doc["effects"]) or "none"})
        for p in ("diagnosis.json", "report.md", "extended_vehicle.yaml"):
            if (outdir / p).exists():
                run.artifact(outdir / p)
