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


def run_diagnosis(flights, vehicle, out, overrides=(), track: bool | None = None, log=None,
                  return_result: bool = False):
    from ..atomic import atomic_dir, write_json
    from ..config import to_dict
    from ..flight import read_flight
    from ..vehicle import load_vehicle, save_vehicle
    from .core import DiagnoseConfig, diagnose, extended_effects
    from .report import make_figures, to_json, write_report

    say = log or (lambda msg: print(f"qr diagnose: {msg}", file=sys.stderr))
    cfg = _compose(overrides)
    dcfg_dict = to_dict(cfg.diagnose)
    dcfg = DiagnoseConfig.from_dict(dcfg_dict)
    vehicle = load_vehicle(vehicle)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise QrInputError(out, "output path exists and is not a directory", "give a directory for --out")
    measured = [read_flight(f, vehicle) for f in flights]
    for f, m in zip(flights, measured):
        if m["t"].iloc[-1] - m["t"].iloc[0] < 4 * dcfg.block_s + dcfg.gap_s:
            raise QrInputError(f, f"flight lasts {m['t'].iloc[-1] - m['t'].iloc[0]:.1f} s, too short to hold out "
                                  "a test part", "give a longer flight (30 s or more) or several flights")
    states, pairs = [], []
    from ..estimation import estimate
    from .crossfit import halves, matched_settings
    from .matched import add_matched_rotor_signals

    for i, m in enumerate(measured):
        say(f"filtering {Path(flights[i]).name} ({len(m)} samples, filter={cfg.filter.get('name', '?')})")
        st, report = estimate(m, vehicle, to_dict(cfg.filter))
        matched = matched_settings(to_dict(cfg.filter), report)
        st, _ = estimate(m, vehicle, matched)
        states.append(add_matched_rotor_signals(st, m, matched))
        pairs.append(halves(m, vehicle, matched))
    say("identifying effects")
    res = diagnose(states, measured, vehicle, dcfg, seed=int(cfg.seed), progress=lambda s: say(s), pairs=pairs)
    from .remainder import remainder

    say("checking for structure beyond the catalog")
    res["remainder"] = remainder(res, vehicle, dcfg)
    doc = to_json(res, [Path(f).name for f in flights], dcfg_dict)
    doc["filter"] = to_dict(cfg.filter)
    ext = vehicle.with_changes(effects=vehicle.effects + extended_effects(res["effects"]))
    with atomic_dir(out) as tmp:
        figs = make_figures(tmp, res, vehicle)
        write_report(tmp, doc, res, figs)
        write_json(tmp / "diagnosis.json", doc)
        save_vehicle(ext, tmp / "extended_vehicle.yaml",
                     header=f"Extended vehicle from qr diagnose of {', '.join(doc['flights'])}: "
                            "the nominal parameters plus the named effects")
    if track if track is not None else bool(cfg.diagnose.get("track", False)):
        from .. import tracking

        with tracking.run("diagnose", out.name, {"diagnose": dcfg_dict, "filter": doc["filter"]},
                          inputs=flights) as run:
            run.metrics({"nominal_loss": res["nominal_loss"], "extended_loss": res["extended_loss"],
                         "effects_named": len(res["effects"]),
                         "replay.nominal_position_rmse": doc["replay"]["nominal_position_rmse"],
                         "replay.extended_position_rmse": doc["replay"]["extended_position_rmse"]})
            run.tags({"qr.effects": ",".join(e["name"] for e in res["effects"]) or "none"})
            for p in ("diagnosis.json", "report.md", "extended_vehicle.yaml"):
                run.artifact(out / p)
    say(doc["verdict"])
    return (doc, res) if return_result else doc
