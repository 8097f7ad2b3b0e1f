"""Stage ``diagnose``: ``qr diagnose`` and the workflow's measured-data diagnoses (file I/O and MLflow).

Contract: docs/spec/diagnosis.md.  ``run_diagnosis`` reads the flights
and the vehicle, takes each segment's estimates from the filter stage's cross-fit file or filters it
(the same function, :func:`qr.diagnose.crossfit.prepare_flight`), diagnoses (:mod:`qr.diagnose.core`)
and writes ``OUTDIR/diagnosis.json``, ``report.md``, ``figures/`` and ``extended_vehicle.yaml``, all at
once (built in a temporary folder, then moved into place) and nothing anywhere else.  Where it writes
is checked first (:func:`qr.outputs.check_out_dir`): qr never replaces a file it did not write.

The workflow's chain (``diagnose_set``, ``diagnose_each``, ``carry_over``, ``summary``), in an
engineer's order (issue 5): diagnose the vehicle without payload first; carry its extended model over
to the payload flights (with the payload frame's own mass); diagnose those; compare.  The filter
stage's tuned noise values are reused (``.nis.json``), so nothing is tuned twice.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pandas as pd
import yaml

from ..atomic import atomic_dir
from ..errors import QrInputError
from ..report.tables import write_table
from ..vehicle import load_vehicle, save_vehicle, vehicle_from_dict


def _compose(overrides):
    from ..config import compose_stage

    return compose_stage(overrides, "diagnose", "diagnose.horizon_s=2")


# what OUTDIR receives (a folder name ends in "/"): checked against the user's files before any work
OUTPUTS = ("diagnosis.json", "report.md", "extended_vehicle.yaml", "figures/")


def run_diagnosis(flights, vehicle, out, overrides=(), track: bool | None = None, log=None,
                  return_result: bool = False, reports: list | None = None, figures: bool = True,
                  force: bool = False, estimates: list | None = None):
    """Diagnose ``flights`` and write ``out`` (refused before any work if ``out`` is not qr's to write,
    :func:`qr.outputs.check_out_dir`; ``force``: write beside a folder's other files).

    ``reports`` / ``estimates``: per flight, the filter stage's report and cross-fit file; a segment
    found there with the same filter settings is read, not filtered again (the same numbers)."""
    from ..parallel import blas_one_thread

    background = []  # figures drawn by a child process: stopped and removed however the run ends
    try:
        with blas_one_thread():  # qr's own threads use the cores
            return _run_diagnosis(flights, vehicle, out, overrides, track, log, return_result, reports, figures,
                                  force, estimates, background)
    finally:
        for b in background:
            b.close()


def _run_diagnosis(flights, vehicle, out, overrides, track, log, return_result, reports, figures, force, estimates,
                   background):
    from ..outputs import check_out_dir

    out = check_out_dir(out, inputs=[*flights, vehicle], force=force, expected=OUTPUTS)
    from ..flight import read_flight

    # the inputs first: a file that is missing or wrong is refused before the heavy imports and Hydra
    vehicle_path, vehicle = vehicle, load_vehicle(vehicle)
    # validated without the vehicle: its unit check needs the ground rows known (qr.airborne)
    measured = [read_flight(f) for f in flights]

    from .. import conventions
    from ..atomic import write_json
    from ..config import to_dict
    from ..estimation.settings import resolve as resolve_filter
    from ..flight import hover_ratio
    from ..segments import flight_segments
    from ..diagnose.coefficients import coefficient_checks
    from ..diagnose.crossfit import Estimates, prepare_flight
    from ..torque_remainder import FEATURES
    from ..diagnose.core import DiagnoseConfig, diagnose, extended_effects
    from ..diagnose.report import anatomy_figure, make_figures, note_nulls, to_json, write_report
    from ..report.background import BackgroundFigure

    say = log or (lambda msg: print(f"qr diagnose: {msg}", file=sys.stderr))
    cfg = _compose(overrides)
    dcfg_dict = to_dict(cfg.diagnose)
    dcfg = DiagnoseConfig.from_dict(dcfg_dict)
    resolve_filter(to_dict(cfg.filter))  # the filter settings too, before any work
    # the training part of a lone flight must hold a block per cross-validation fold
    blocks = dcfg.selection.folds if len(flights) == 1 else 1
    need = (blocks * dcfg.block_s + dcfg.gap_s / 2) / dcfg.train_fraction
    split, checks = [], []
    for f, m in zip(flights, measured):
        fs = flight_segments(m, vehicle, 2 * dcfg.trim_s + dcfg.block_s, f)
        checks.append({"flight": str(f), "checks": [r.as_dict() for r in conventions.require(
            m, vehicle, f, dcfg.skip_checks, "diagnose.skip_checks=[{name}] at the end of the command")]})
        _check_length(f, fs, need, dcfg, blocks)
        split.append(fs)
    work = []  # (flight, segment start, state table, cross-fitting pair, measured rows)
    for i, fs in enumerate(split):
        name = Path(flights[i]).name
        _say_segments(say, name, fs)
        report = reports[i] if reports else None
        stored = Estimates(estimates[i], to_dict(cfg.filter), report, vehicle) if estimates and report else None
        # the longest segment first: a tuning filter (filter=auto) is tuned there, once per flight
        for seg in sorted(fs.used, key=lambda s: s.window[0] - s.window[1]):
            got = stored.get(seg.window[0]) if stored else None
            if got:
                st, pair = got
                source = "read from the filter stage"
            else:
                st, pair, report = prepare_flight(seg.rows, vehicle, to_dict(cfg.filter), report)
                source = f"filter={cfg.filter.get('name', '?')}"
            say(f"estimates of {name} {seg.window[0]:.2f}-{seg.window[1]:.2f} s ({len(seg.rows)} samples): "
                f"{source}")
            for table in (st, *pair):
                table.attrs["flight"] = i  # qr.diagnose.core.prepare: one flight, split once
            work.append((i, seg.window[0], st, pair, seg.rows))
    work.sort(key=lambda w: w[:2])  # flights in order, each one's segments in time order
    _, _, states, pairs, pieces = (list(x) for x in zip(*work))
    say("identifying effects")

    def draw_anatomy(prep):  # it needs only the nominal residuals: drawn while the selection runs
        background.append(BackgroundFigure(lambda path: anatomy_figure(prep, vehicle, path)))

    res = diagnose(states, pieces, vehicle, dcfg, seed=int(cfg.seed), progress=lambda s: say(s), pairs=pairs,
                   prepared=draw_anatomy if figures else None)
    from ..rollout import EvaluateConfig
    from ..diagnose.core import rollout_all, summed_r2
    from ..diagnose.remainder import remainder

    ext = vehicle.with_changes(effects=vehicle.effects + extended_effects(res["effects"]))
    hybrid = None
    if dcfg.torque_remainder_ridge > 0:
        from .. import torque_remainder as trm
        from ..diagnose.core import fit_torque_remainder

        say("fitting the learned torque remainder")
        rem = res["torque_remainder"] = fit_torque_remainder(res, vehicle, dcfg.torque_remainder_ridge)
        W = rem["weights"] + (trm.weights(vehicle) if trm.weights(vehicle) is not None else 0.0)
        hybrid = ext.with_changes(torque_remainder=trm.block(
            W, f"learned on the training part of {', '.join(Path(f).name for f in flights)} (ridge "
               f"{dcfg.torque_remainder_ridge:g}): not a physical effect"))
    from concurrent.futures import ThreadPoolExecutor

    from ..diagnose.accelerometer import accelerometer_check

    # the check for structure beyond the catalog (numpy) runs beside the rollout (compiled, the GIL
    # released): neither reads what the other writes
    with ThreadPoolExecutor(1) as pool:
        checked = pool.submit(remainder, res, vehicle, dcfg)
        say("rolling out the nominal and the extended model on the held-out part")
        ecfg = EvaluateConfig.from_dict(to_dict(cfg.evaluate))
        res["rollout"] = rollout_all(states, pieces, vehicle, res["effects"], res["prep"], ecfg.horizon,
                                     ecfg.max_input_gap, 0.0, hybrid)
        prep = res["prep"]
        y_test = prep.y[prep.test]
        res["rollout"]["explained"] = summed_r2(prep, y_test, y_test - res["pred_test"], ecfg.horizon)
        res["accelerometer_check"] = accelerometer_check(states, pieces, vehicle, dcfg.trim_s)
        say("checking for structure beyond the catalog")
        res["remainder"] = checked.result()
    if dcfg.refine == "rollout":  # physical parameters by simulation error (qr.diagnose.refine)
        from ..diagnose.refine import refine_diagnosis

        res["refine"] = refine_diagnosis(states, pieces, res["prep"].windows, vehicle, res["effects"], dcfg, ecfg,
                                         int(cfg.seed), say)
        ext = (hybrid or ext).with_changes(effects=vehicle.effects + res["refine"].effects(extended_effects(res["effects"])))
        hybrid = ext if hybrid else None
    doc = to_json(res, [str(f) for f in flights], dcfg_dict)  # each flight as the user gave it
    doc["filter"] = to_dict(cfg.filter)
    doc["accelerometer_check"] = res["accelerometer_check"]
    if "torque_remainder" in res:
        rem = res["torque_remainder"]
        doc["torque_remainder"] = {"ridge": rem["ridge"], "features": FEATURES,
                                   "extended_torque_rmse": rem["extended_torque_rmse"],
                                   "hybrid_torque_rmse": rem["hybrid_torque_rmse"]}
    if "refine" in res:
        doc["refine"] = res["refine"].to_json()
    doc.update(segments_json(doc["flights"], split))
    doc["conventions"] = checks
    hover = hover_ratio(pd.concat(measured, ignore_index=True), vehicle)
    doc["vehicle_file"], doc["vehicle_file_unresolved"] = coefficient_checks(doc["effects"], vehicle, vehicle_path,
                                                                             res["evidence"], hover)
    if doc["vehicle_file"]:
        doc["verdict"] += " " + " ".join(c["statement"][0].upper() + c["statement"][1:] + "."
                                         for c in doc["vehicle_file"])
    strict = note_nulls(doc)  # diagnosis.json: null (and a note) where the report prints nan
    ext = hybrid or ext
    with atomic_dir(out, force=force, command="qr diagnose") as tmp:
        figs = make_figures(tmp, res, vehicle, background[0] if background else None) if figures else {}
        write_report(tmp, doc, res, figs)
        write_json(tmp / "diagnosis.json", strict)
        save_vehicle(ext, tmp / "extended_vehicle.yaml",
                     header=f"Extended vehicle from qr diagnose of {', '.join(doc['flights'])}: "
                            "the nominal parameters plus the named effects"
                            + ("; their parameters and J, C_T, C_Q, the delay refined by the rollout's error "
                               "where the refinement may write them (diagnosis.json: refine)" if "refine" in res else ""))
    if track if track is not None else bool(cfg.diagnose.get("track", False)):
        track_diagnosis(out.name, doc, flights, out, {"nominal_loss": res["nominal_loss"],
                                                      "extended_loss": res["extended_loss"]})
    say(doc["verdict"])
    return (strict, res) if return_result else strict


def _check_length(path, fs, need: float, dcfg, blocks: int) -> None:
    """Refuse a flight whose used segments, less ``trim_s`` at each end, cannot hold ``need`` seconds."""
    longest = max(s.window[1] - s.window[0] for s in fs.segments)
    n = len(fs.used)
    lasts = sum(s.window[1] - s.window[0] for s in fs.used)
    fits = ((lasts - 2 * dcfg.trim_s * n) * dcfg.train_fraction - dcfg.gap_s / 2) / blocks  # the block that fits
    shorter = (f", or shorter cross-validation blocks: add diagnose.block_s={math.floor(10 * fits) / 10:g} "
               "at the end of the command" if fits >= 0.5 else "")
    fix = f"give a longer flight (30 s or more) or several flights{shorter}"
    if not fs.used:
        raise QrInputError(path, f"no airborne stretch without a time gap lasts {2 * dcfg.trim_s + dcfg.block_s:.1f} s "
                                 f"(2 trim_s + block_s; the longest: {longest:.1f} s)", fix)
    if lasts - 2 * dcfg.trim_s * n < need:
        where = "airborne" if not fs.gaps else f"airborne in {n} segment{'s' if n > 1 else ''} between time gaps"
        raise QrInputError(path, f"flight lasts {lasts:.1f} s {where}, too short to hold out a test part "
                                 f"(needs {need + 2 * dcfg.trim_s * n:.1f} s)", fix)


def _say_segments(say, name, fs) -> None:
    if fs.ground_s > 0:
        spans = ", ".join(f"{a:.2f}-{b:.2f} s" for a, b in fs.airborne)
        say(f"{name}: airborne {spans}; {fs.ground_s:.1f} s on the ground left out")
    for g0, g1 in fs.gaps:
        say(f"{name}: no samples from {g0:.2f} to {g1:.2f} s: the parts before and after are separate segments")
    for seg in fs.segments:
        if not seg.used:
            say(f"{name}: segment {seg.window[0]:.2f}-{seg.window[1]:.2f} s not used: {seg.note}")


def segments_json(names: list[str], split) -> dict:
    """``diagnosis.json``'s account of the data used: airborne windows, time gaps, segments (flight time, s)."""
    r = lambda x: round(float(x), 4)  # noqa: E731
    airborne, gaps, segments = [], [], []
    for name, fs in zip(names, split):
        airborne.append({"flight": name, "window": [r(fs.airborne[0][0]), r(fs.airborne[-1][1])],
                         "dropped_s": r(fs.ground_s)})
        if len(fs.airborne) > 1:
            airborne[-1]["windows"] = [[r(a), r(b)] for a, b in fs.airborne]
        gaps += [{"flight": name, "from": r(a), "to": r(b)} for a, b in fs.gaps]
        for seg in fs.segments:
            segments.append({"flight": name, "window": [r(x) for x in seg.window], "samples": len(seg.rows),
                             "used": seg.used, **({"note": seg.note} if seg.note else {})})
    return {"airborne": airborne, "time_gaps": gaps, "segments": segments}


def track_diagnosis(name, doc: dict, inputs, outdir, metrics: dict | None = None) -> None:
    """One MLflow run (experiment ``qr-diagnose``) for a written diagnosis in ``outdir``."""
    from .. import tracking

    outdir = Path(outdir)
    with tracking.run("diagnose", name, {"diagnose": doc["config"], "filter": doc.get("filter", {})},
                      inputs=inputs, description=doc["verdict"]) as run:
        run.metrics({**(metrics or {}), "effects_named": len(doc["effects"]),
                     "replay.nominal_position_rmse": doc["replay"]["nominal_position_rmse"],
                     "replay.extended_position_rmse": doc["replay"]["extended_position_rmse"],
                     **_rollout_metrics(doc.get("rollout"))})
        run.tags({"qr.effects": ",".join(e["name"] for e in doc["effects"]) or "none"})
        for p in ("diagnosis.json", "report.md", "extended_vehicle.yaml"):
            if (outdir / p).exists():
                run.artifact(outdir / p)


def _rollout_metrics(ro: dict | None) -> dict:
    """``rollout.<model>.<q>_at_<H>`` and ``..._ratio`` (to rate_frozen) of the diagnosis's rollout block."""
    from ..rollout import horizon_metrics

    if not (ro and ro.get("models")):
        return {}
    return horizon_metrics(ro["models"], ro["horizon"], prefix="rollout.", ratios=True)


def _reports(nis_files):
    return [json.loads(Path(p).read_text()) for p in nis_files]


def diagnose_set(flights, nis_files, vehicle, out, overrides=(), track=True, estimates=None) -> dict:
    """One diagnosis of all ``flights`` together (canonical flights + their filter reports and, if given,
    the filter stage's cross-fit estimates)."""
    return run_diagnosis(flights, vehicle, out, overrides, track=track, reports=_reports(nis_files),
                         estimates=estimates)


def diagnose_each(flights, nis_files, vehicle, out_dir, table, overrides=(), estimates=None) -> pd.DataFrame:
    """A diagnosis per flight (no figures: short flights, many of them) and one table of them."""
    rows = []
    reports = _reports(nis_files)
    estimates = estimates or [None] * len(flights)
    with atomic_dir(out_dir) as tmp:
        for f, rep, est in zip(flights, reports, estimates):
            name = Path(f).stem
            doc = run_diagnosis([f], vehicle, tmp / name, overrides, track=False, reports=[rep], figures=False,
                                log=lambda m: None, estimates=[est] if est else None)
            track_diagnosis(f"{Path(out_dir).parent.name}/{name}", doc, [f], tmp / name)
            rows.append({
                "flight": name,
                "effects": ", ".join(e["name"] for e in doc["effects"]) or "-",
                **{f"{e['name']}.{k}": v for e in doc["effects"] for k, v in e["parameters"].items()},
                "nominal_fz_rmse": doc["nominal"]["force_rmse"][2],
                "extended_fz_rmse": doc["extended"]["force_rmse"][2],
                "noise_fz_rmse": doc["noise_floor"]["force_rmse"][2],
            })
    df = pd.DataFrame(rows)
    write_table(df, table, title=f"Per-flight diagnoses ({Path(out_dir).parent.name})")
    return df


def carry_over(extended_vehicle, base_vehicle, out) -> None:
    """The payload frame = the no-payload diagnosis's extended vehicle with the payload frame's own mass."""
    ext = yaml.safe_load(Path(extended_vehicle).read_text())
    base = load_vehicle(base_vehicle)
    ext["mass"] = base.mass
    ext["name"] = f"{base.name} (effects carried over from {ext.get('name', 'the no-payload diagnosis')})"
    save_vehicle(vehicle_from_dict(ext), out,
                 header=f"{base.name}: mass from {Path(base_vehicle).name}, effects from {extended_vehicle}")



def summary(set_dirs: dict, table) -> pd.DataFrame:
    """The set diagnoses side by side: named effects, RMSEs, replay."""
    rows = []
    for name, d in set_dirs.items():
        doc = json.loads((Path(d) / "diagnosis.json").read_text())
        eff = "; ".join(f"{e['name']}(" + ", ".join(f"{k}={v:.4g}" for k, v in e["parameters"].items()) + ")"
                        for e in doc["effects"]) or "none"
        rows.append({
            "set": name, "flights": len(doc["flights"]), "samples": doc["samples"], "named": eff,
            "nominal_force_rmse": " / ".join(f"{x:.4f}" for x in doc["nominal"]["force_rmse"]),
            "extended_force_rmse": " / ".join(f"{x:.4f}" for x in doc["extended"]["force_rmse"]),
            "noise_force_rmse": " / ".join(f"{x:.4f}" for x in doc["noise_floor"]["force_rmse"]),
            "nominal_torque_rmse": " / ".join(f"{x:.2e}" for x in doc["nominal"]["torque_rmse"]),
            "extended_torque_rmse": " / ".join(f"{x:.2e}" for x in doc["extended"]["torque_rmse"]),
            "replay_nominal_m": doc["replay"]["nominal_position_rmse"],
            "replay_extended_m": doc["replay"]["extended_position_rmse"],
            "remainder": (doc.get("remainder") or {}).get("correlated_with") or "-",
        })
    df = pd.DataFrame(rows)
    write_table(df, table, title="Diagnoses of the measured flight sets")
    return df
