"""Stage ``diagnose``: ``qr diagnose`` and the workflow's measured-data diagnoses (file I/O and MLflow).

Contract: docs/spec/diagnosis.md.  ``run_diagnosis`` reads (the flights and the vehicle, the settings,
each segment's estimates from the filter stage's cross-fit file or filtered:
:func:`qr.estimation.crossfit.diagnosis_estimates`), runs (:func:`qr.diagnose.run`), writes
``OUTDIR/diagnosis.json``, ``report.md``, ``figures/`` and ``extended_vehicle.yaml`` all at once (built
in a temporary folder, then moved into place; nothing anywhere else) and tracks.  Where it writes is
checked first (:func:`qr.outputs.check_out_dir`): qr never replaces a file it did not write.

The workflow's chain (``diagnose_set``, ``diagnose_each``, ``carry_over``, ``summary``), in an
engineer's order (issue 5): diagnose the vehicle without payload first; carry its extended model over
to the payload flights (with the payload frame's own mass); diagnose those; compare.  The filter
stage's tuned noise values are reused (``.nis.json``), so nothing is tuned twice.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pandas as pd
import yaml

from ..atomic import atomic_dir, write_json
from ..outputs import check_out_dir
from ..parallel import blas_one_thread
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
    background = []  # figures drawn by a child process: stopped and removed however the run ends
    try:
        with blas_one_thread():  # qr's own threads use the cores
            return _run_diagnosis(flights, vehicle, out, overrides, track, log, return_result, reports, figures,
                                  force, estimates, background)
    finally:
        for b in background:
            b.close()


def _run_diagnosis(flights, vehicle_file, out, overrides, track, log, return_result, reports, figures, force,
                   estimates, background):
    out = check_out_dir(out, inputs=[*flights, vehicle_file], force=force, expected=OUTPUTS)
    say = log or (lambda msg: print(f"qr diagnose: {msg}", file=sys.stderr))
    plotting = _Plotting() if figures else None
    settings, read, work, vehicle = _read(flights, vehicle_file, overrides, reports, estimates, say, plotting)
    if plotting:
        plotting.ready()  # before any fork: a child must not inherit an import half done
    diagnosis = _run(work, read, vehicle, vehicle_file, settings, say, background if figures else None)
    doc = _write(out, diagnosis, vehicle, figures, background[0] if background else None, force)
    if track if track is not None else bool(settings.given.get("track", False)):
        track_diagnosis(out.name, doc, flights, out, {"nominal_loss": diagnosis.held_out.nominal_loss,
                                                      "extended_loss": diagnosis.held_out.extended_loss})
    say(diagnosis.verdict)
    return (doc, diagnosis) if return_result else doc


class _Plotting:
    """matplotlib and the report's figures imported on a thread while the filters run (their compiled
    kernels release the GIL): a third of a second a user no longer waits for."""

    def __init__(self):
        import threading

        self._thread = threading.Thread(target=self._load, daemon=True)

    @staticmethod
    def _load():
        from ..diagnose import report  # noqa: F401  (imports qr.report.figures, matplotlib)

    def start(self):
        self._thread.start()

    def ready(self):
        if self._thread.is_alive() or self._thread.ident is not None:
            self._thread.join()


def _read(flights, vehicle_file, overrides, reports, estimates, say, plotting=None):
    """(settings, the flights checked, every used segment's estimates, the vehicle): the estimates read
    from the filter stage's cross-fit files or filtered (``plotting`` imported meanwhile)."""
    from ..flight import read_flight

    # the inputs first: a file that is missing or wrong is refused before the heavy imports and Hydra
    vehicle = load_vehicle(vehicle_file)
    # validated without the vehicle: its unit check needs the ground rows known (qr.airborne)
    measured = [read_flight(f) for f in flights]
    from ..diagnose.diagnosis import Settings
    from ..diagnose.flights import check_flights
    from ..estimation.crossfit import diagnosis_estimates

    settings = Settings.of(_compose(overrides))
    read = check_flights([str(f) for f in flights], measured, vehicle, settings.diagnose, say, vehicle_file)
    if plotting:
        plotting.start()
    work = diagnosis_estimates([fs.used for fs in read.split], [Path(f).name for f in flights], vehicle,
                               settings.filter, reports, estimates, say)
    return settings, read, work, vehicle


def _run(work, read, vehicle, vehicle_file, settings, say, background: list | None):
    """:func:`qr.diagnose.run`; with ``background``, the residual anatomy figure is drawn by a child
    process while the fit runs (it needs only the nominal residuals)."""
    from ..diagnose.diagnosis import run
    from ..diagnose.report import anatomy_figure
    from ..report.background import BackgroundFigure

    def draw_anatomy(prep):
        background.append(BackgroundFigure(lambda path: anatomy_figure(prep, vehicle, path)))

    say("identifying effects")
    return run(work, read, vehicle, settings, vehicle_file, say, draw_anatomy if background is not None else None)


def _write(out, diagnosis, vehicle, figures: bool, anatomy, force: bool) -> dict:
    """``out``: diagnosis.json, report.md (and its figures), extended_vehicle.yaml, all at once; the
    document written."""
    from ..diagnose.document import document
    from ..diagnose.report import make_figures, write_report

    doc = document(diagnosis)
    with atomic_dir(out, force=force, command="qr diagnose") as tmp:
        figs = make_figures(tmp, diagnosis, vehicle, anatomy) if figures else {}
        write_report(tmp, diagnosis, figs, vehicle)
        write_json(tmp / "diagnosis.json", doc)
        save_vehicle(diagnosis.extended_vehicle, tmp / "extended_vehicle.yaml",
                     header=f"Extended vehicle from qr diagnose of {', '.join(doc['flights'])}: "
                            + ("the vehicle as given, nothing added: the model does not describe this flight "
                               "(diagnosis.json: described, misfit; what it identifies is in its effects)"
                               if not diagnosis.described else
                               "the nominal parameters plus the named effects"
                               + ("; their parameters and J, C_T, C_Q, the delay refined by the rollout's error "
                                  "where the refinement may write them (diagnosis.json: refine)"
                                  if diagnosis.refinement is not None else "")))
    return doc


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
    veh = load_vehicle(vehicle)
    with atomic_dir(out_dir) as tmp:
        for f, rep, est in zip(flights, reports, estimates):
            name = Path(f).stem
            doc = run_diagnosis([f], vehicle, tmp / name, overrides, track=False, reports=[rep], figures=False,
                                log=lambda m: None, estimates=[est] if est else None)
            track_diagnosis(f"{Path(out_dir).parent.name}/{name}", doc, [f], tmp / name)
            rows.append({
                "flight": name,
                "effects": ", ".join(e["name"] for e in doc["effects"]) or "-",
                **{f"{e['name']}.{k}" + _unit_suffix(e["name"], k, veh): v for e in doc["effects"]
                   for k, v in e["parameters"].items()},
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



def _unit_suffix(name: str, param: str, vehicle=None) -> str:
    """A table column's unit: ``' (N s/m)'``, nothing for a ratio."""
    from ..effects import DIMENSIONLESS, unit

    u = unit(name, param, vehicle)
    return "" if u in ("", DIMENSIONLESS) else f" ({u})"


def summary(set_dirs: dict, table) -> pd.DataFrame:
    """The set diagnoses side by side: named effects, RMSEs, replay."""
    rows = []
    for name, d in set_dirs.items():
        doc = json.loads((Path(d) / "diagnosis.json").read_text())
        from ..effects import effects_with_units

        eff = effects_with_units(doc["effects"]) or "none"
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
