"""Stage ``diagnose``: ``qr diagnose`` (file I/O and MLflow; contract: docs/spec/diagnosis.md).

``run_diagnosis`` checks where it writes (:func:`qr.outputs.check_out_dir`: qr never replaces a file it did
not write), takes the flights (:mod:`qr.intake`: convention checks, segments, each segment's estimates from the
filter stage's cross-fit file or filtered), runs :func:`qr.diagnose.run`, writes ``OUTDIR/diagnosis.json``,
``report.md``, ``figures/`` and ``extended_vehicle.yaml`` all at once (built in a temporary folder, then moved
into place) and tracks.  The workflow's set-level chain is :mod:`qr.stages.diagnose_sets`.
"""

from __future__ import annotations

import sys
from pathlib import Path

from ..atomic import atomic_dir, write_json
from ..intake import read_flights, take
from ..outputs import check_out_dir
from ..parallel import blas_one_thread
from ..vehicle import load_vehicle, save_vehicle

# what OUTDIR receives (a folder name ends in "/"): checked against the user's files before any work
OUTPUTS = ("diagnosis.json", "report.md", "extended_vehicle.yaml", "figures/")


def run_diagnosis(flights, vehicle, out, overrides=(), track: bool | None = None, log=None,
                  return_result: bool = False, reports: list | None = None, figures: bool = True,
                  force: bool = False, estimates: list | None = None, memo=None):
    """Diagnose ``flights`` and write ``out`` (refused before any work if ``out`` is not qr's to write;
    ``force``: write beside a folder's other files); the document written (and the Diagnosis: ``return_result``).

    ``reports`` / ``estimates``: per flight, the filter stage's report and cross-fit file; a segment
    found there with the same filter settings is read, not filtered again (the same numbers).  ``memo``: what an
    earlier command of this process took (:class:`qr.intake.Memo`)."""
    out = check_out_dir(out, inputs=[*flights, vehicle], force=force, expected=OUTPUTS)
    say = log or (lambda msg: print(f"qr diagnose: {msg}", file=sys.stderr))
    with blas_one_thread():  # qr's own threads use the cores
        # the inputs first: a file that is missing or wrong is refused before the heavy imports and Hydra
        veh, measured = load_vehicle(vehicle), read_flights(flights, memo)
        from ..diagnose.diagnosis import Settings, run
        from ..diagnose.document import document, vehicle_header
        from ..diagnose.drawing import Drawing
        from ..diagnose.flights import intake_settings, length_check

        settings = Settings.composed(overrides)
        with Drawing(veh) as drawing:
            taken = take([str(f) for f in flights], measured, veh, intake_settings(settings.diagnose, settings.filter),
                         vehicle, reports, estimates, say, length_check(settings.diagnose, len(flights)),
                         drawing.start if figures else None, memo)
            drawing.ready()
            say("identifying effects")
            diagnosis = run(list(taken.estimates), taken.flights, veh, settings, vehicle, say,
                            drawing.draw_anatomy if figures else None)
            doc = document(diagnosis)
            from ..diagnose.report import make_figures, write_report

            with atomic_dir(out, force=force, command="qr diagnose") as tmp:
                figs = make_figures(tmp, diagnosis, veh, drawing.anatomy) if figures else {}
                write_report(tmp, diagnosis, figs, veh)
                write_json(tmp / "diagnosis.json", doc)
                save_vehicle(diagnosis.extended_vehicle, tmp / "extended_vehicle.yaml", header=vehicle_header(diagnosis))
    if track if track is not None else bool(settings.given.get("track", False)):
        track_diagnosis(out.name, doc, flights, out, {"nominal_loss": diagnosis.held_out.nominal_loss,
                                                      "extended_loss": diagnosis.held_out.extended_loss})
    say(diagnosis.verdict)
    return (doc, diagnosis) if return_result else doc


def track_diagnosis(name, doc: dict, inputs, outdir, metrics: dict | None = None) -> None:
    """One MLflow run (experiment ``qr-diagnose``) for a written diagnosis in ``outdir``."""
    from .. import tracking
    from ..diagnose.document import run_metrics

    with tracking.run("diagnose", name, {"diagnose": doc["config"], "filter": doc.get("filter", {})},
                      inputs=inputs, description=doc["verdict"]) as run:
        run.metrics({**(metrics or {}), **run_metrics(doc)})
        run.tags({"qr.effects": ",".join(e["name"] for e in doc["effects"]) or "none"})
        for p in ("diagnosis.json", "report.md", "extended_vehicle.yaml"):
            if (Path(outdir) / p).exists():
                run.artifact(Path(outdir) / p)
