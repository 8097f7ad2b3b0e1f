"""Stage learn, ``qr learn residual``: a residual trained through the rollout (docs/spec/hybrid.md).

    qr learn residual FLIGHT.csv [FLIGHT2.csv ...] --vehicle VEHICLE.yaml --out OUTDIR [HYDRA_OVERRIDES...]

Reads the flights and the vehicle, checks where the output goes, trains (:func:`qr.residual_training.run`:
the flights' windows, split and filtered by the one path ``qr evaluate`` uses), then writes
``OUTDIR/hybrid_vehicle.yaml`` (the vehicle plus the key ``residual``), ``residual.npz`` (the weights,
:mod:`qr.residual`), ``training.json`` (schema ``qr.residual/1``), ``report.md``, ``figures/`` and, with
the band's ensemble, ``members/`` and ``hybrid_vehicle.bands.json``, all at once.  An MLflow run in
experiment ``qr-learn`` logs the settings, the loss per epoch, the validation MAE per step h (metric
steps) and the model (``mlflow.pytorch``, with its signature).  A sweep (``-m``), the held-out protocol's
training and the carried network: :mod:`qr.stages.learn_residual_sets`.
"""

from __future__ import annotations

import sys

from ..atomic import atomic_dir, write_json, write_text
from ..outputs import check_out_dir

OUTPUTS = ("hybrid_vehicle.yaml", "residual.npz", "training.json", "report.md", "figures/",
           "hybrid_vehicle.bands.json", "members/")


def compose(overrides=()):
    """The tree with ``learn=residual`` (``learn.*``: :class:`qr.residual_fit.ResidualNode`)."""
    from ..config import compose_stage

    return compose_stage(["learn=residual", *overrides], "evaluate", "learn.width=16")


def run_residual(flights, vehicle, out, overrides=(), force: bool = False, log=None, cfg=None,
                 reports: list | None = None, estimates: list | None = None, track: bool = True,
                 run_name: str = "residual", parent_id: str | None = None, split=None, memo=None) -> dict:
    """Train on ``flights`` on top of ``vehicle``; write ``out`` (checked before any work); the
    training.json document.  ``cfg``: the composed tree (else composed from ``overrides``);
    ``reports`` / ``estimates``: the filter stage's files of each flight (as :func:`qr.stages.evaluate.
    run_evaluation` takes them).  ``split``: a :class:`qr.holdout.SplitConfig` instead of the tree's
    ``evaluate.split``: the validation flights are drawn by it (:func:`qr.holdout.validation`), and a
    flight it scores is refused.  ``memo``: what an earlier command of this process took (:class:`qr.intake.Memo`)."""
    flights = [str(f) for f in flights]
    out = check_out_dir(out, inputs=[*flights, vehicle], force=force, expected=OUTPUTS)
    from ..intake import read_flights
    from ..residual_training import Settings, check_flights, run
    from ..residual_training.document import document
    from ..vehicle import load_vehicle

    say = log or (lambda msg: print(f"qr learn residual: {msg}", file=sys.stderr))
    settings = Settings.of(compose(overrides) if cfg is None else cfg, split)
    infos = check_flights(flights, settings)
    veh = load_vehicle(vehicle)
    r = run(flights, read_flights(flights, memo), infos, veh, vehicle, settings, reports, estimates, say, memo)
    doc = document(r)
    _write(out, force, r, doc)
    if track:
        _track(run_name, parent_id, r, doc, out, [*flights, vehicle])
    say(f"wrote {out}/hybrid_vehicle.yaml ({r.trained.wall_s:.0f} s of training, best epoch {r.trained.best_epoch})")
    return doc


def _write(out, force: bool, r, doc: dict) -> None:
    from .. import ensemble, residual
    from ..residual_training.report import curve_figure, report
    from ..vehicle import load_vehicle, save_vehicle

    with atomic_dir(out, force=force, command="qr learn residual") as tmp:
        residual.save_weights(r.residual, tmp / "residual.npz")
        save_vehicle(r.hybrid_file(tmp / "residual.npz"), tmp / "hybrid_vehicle.yaml", header=r.header)
        load_vehicle(tmp / "hybrid_vehicle.yaml")  # what was written loads (weights, shapes, scaling)
        if r.ensemble is not None:
            e = r.ensemble
            ensemble.write(tmp, list(e.members), e.scale, e.scale50, e.calibrated_on, r.note, r.settings.evaluate.horizon)
        (tmp / "figures").mkdir()
        curve_figure(r, tmp / "figures" / "training_curve.png")
        write_text(tmp / "report.md", report(r))
        write_json(tmp / "training.json", doc)


def _track(name: str, parent_id, r, doc: dict, out, inputs) -> None:
    """One MLflow run (experiment ``qr-learn``): settings, loss per epoch, validation MAE per h, the model."""
    import torch

    from .. import tracking
    from ..residual_training.logged_model import logged_model

    tags = {"qr.run": name, "qr.kind": "residual", **({"mlflow.parentRunId": parent_id} if parent_id else {})}
    config = {"learn": doc["config"]["learn"], "seed": doc["seed"], "evaluate": doc["config"]["evaluate"]}
    with tracking.run("learn", name, config=config, inputs=inputs, tags=tags) as run:
        for e in r.trained.epochs:
            run.metrics({"train_loss": e["train_loss"], "val_loss": e["val_loss"]}, step=e["epoch"])
        for step, metrics in r.validation.metrics().items():
            run.metrics(metrics, step=step)
        run.metrics({"train_wall_s": r.trained.wall_s, "best_epoch": r.trained.best_epoch})
        for p in ("training.json", "report.md", "hybrid_vehicle.yaml", "residual.npz"):
            run.artifact(out / p)
        run.model("pytorch", *logged_model(r.trained.net), [f"torch=={torch.__version__.split('+')[0]}"])
