"""The workflow's glue around ``qr learn residual`` (:mod:`qr.stages.learn_residual`): the held-out
protocol's training (:func:`train_held_out`, rule ``learn_residual``), a network carried onto another
vehicle file (:func:`carry_residual`, rule ``carry_residual``), and a sweep (``-m``, :func:`sweep`): one job
per setting into ``OUTDIR/job<N>/``, collected into ``OUTDIR/sweep.csv``, its MLflow runs children of one
parent run (:class:`ResidualSweep`).  Settings are chosen on the validation windows only: no other flight
is read.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from ..errors import QrInputError
from .learn_residual import compose, run_residual
from .sweep_callback import PARENT_FILE, SweepCallback, parent_id

JOB = __name__.rsplit(".", 1)[-1]  # Hydra's job name for the sweeps' jobs (the task's module, :func:`_job`)
SWEEP_CSV = "sweep.csv"


def train_held_out(flights, vehicle, out, overrides=(), reports: list | None = None,
                   estimates: list | None = None, split=None, **kwargs) -> dict:
    """The held-out protocol's training (the workflow's): the flights ``split`` scores (a
    :class:`qr.holdout.SplitConfig`; default the tree's ``evaluate.split``, itself default ``repeat``:
    every third flight) are held out as ``qr evaluate``'s held-out protocol holds them out
    (:func:`qr.holdout.held_out`) and never opened; the others train, their validation flights drawn
    by the same split (``reports`` / ``estimates``: the filter stage's files, or reports already read, of
    every flight in the same order)."""
    from ..estimation.nis import NisReport
    from ..holdout import held_out
    from ..intake import read_reports

    flights = [str(f) for f in flights]
    if split is None:
        from ..config import to_dict
        from ..rollout import EvaluateConfig

        split = EvaluateConfig.from_dict(to_dict(compose(overrides).evaluate)).split
    train = list(held_out(flights, split).train)
    pick = lambda files: [files[flights.index(f)] for f in train] if files else None  # noqa: E731
    reports = [r if isinstance(r, NisReport) else read_reports([r])[0] for r in pick(reports) or []]
    return run_residual(train, vehicle, out, overrides, reports=reports or None, estimates=pick(estimates),
                        split=split, **kwargs)


def carry_residual(extended_vehicle, hybrid_vehicle, out) -> None:
    """``out/hybrid_vehicle.yaml``: the physical part of ``extended_vehicle`` (its learned torque remainder
    dropped) carrying the network of ``hybrid_vehicle`` (a ``qr learn residual`` output), trained elsewhere:
    the workflow's chain flies the first set's network on the carry-to set's own model, and fine-tunes it."""
    import shutil

    from ..atomic import atomic_dir
    from ..vehicle import load_vehicle, save_vehicle

    raw = load_vehicle(extended_vehicle).to_dict()
    raw.pop("torque_remainder", None)
    res = load_vehicle(hybrid_vehicle)
    model = Path(hybrid_vehicle).parent / res.raw["residual"]["model"]
    # the network copied beside the file: a path to another folder, written from the temporary folder,
    # would be one level off when the output folder already exists (atomic_dir builds inside it then)
    raw["residual"] = {**res.raw["residual"], "model": model.name}
    with atomic_dir(out, command="qr learn residual (carried)") as tmp:
        shutil.copyfile(model, tmp / model.name)
        save_vehicle(raw, tmp / "hybrid_vehicle.yaml",
                     header=f"{extended_vehicle} (physical part) with the network of {hybrid_vehicle}, carried over")
        load_vehicle(tmp / "hybrid_vehicle.yaml")


# ---- a sweep: a Hydra multirun (qr learn residual -m) -------------------------------------------------

def _quoted(s: str) -> str:
    return "'" + str(s).replace("\\", "\\\\").replace("'", "\\'") + "'"


def sweep(flights, vehicle, out, overrides, force: bool = False) -> None:
    """``qr learn residual -m``: one job per setting of the Hydra ``overrides`` (comma-separated values)."""
    from ..config import hydra_app, selects_filter, stage_filter
    from ..outputs import check_out_dir

    check_out_dir(out, inputs=[*flights, vehicle], force=force, expected=(SWEEP_CSV, "multirun.yaml"))
    if not selects_filter(overrides):
        # the filter the windows start from is evaluate.filter's, as in a single run (compose_stage)
        named = stage_filter("evaluate", overrides)
        if "," in named:
            raise QrInputError("evaluate.filter", "a sweep over the filter is given as evaluate.filter",
                               "sweep it as filter=auto,smoother")
        overrides = [*overrides, f"filter={named}"]
    given = ["learn=residual", f"learn.flights=[{','.join(_quoted(f) for f in flights)}]",
             f"learn.vehicle={_quoted(vehicle)}", f"learn.out={_quoted(out)}", f"learn.force={str(force).lower()}",
             f"hydra.sweep.dir={_quoted(out)}", "hydra.sweep.subdir='job${hydra.job.num}'"]
    argv, sys.argv = sys.argv, ["qr learn residual", "-m", *given, *overrides]
    try:
        hydra_app("learn residual", _job)
    finally:
        sys.argv = argv


def _job(cfg) -> float:
    """One job of a sweep (Hydra calls it with the composed tree)."""
    from hydra.core.hydra_config import HydraConfig

    hc = HydraConfig.get()
    learn = cfg.learn
    out = Path(learn.out)
    name = f"job{int(hc.job.num)}"
    doc = run_residual(list(learn.flights), learn.vehicle, out / name, force=bool(learn.force), cfg=cfg,
                       run_name=name, parent_id=parent_id(out))
    return float(min(e["val_loss"] for e in doc["loss_per_epoch"]))


def collect(out, since: float = 0.0) -> "pd.DataFrame":  # noqa: F821
    """One row per job of a sweep (its training.json written after ``since``, a time stamp): settings,
    epochs, best validation loss and ratios at H."""
    import json

    import pandas as pd

    from ..rollout import QUANTITIES

    rows = []
    for p in sorted(Path(out).glob("job*/training.json"), key=lambda p: int(p.parent.name[3:])):
        if p.stat().st_mtime < since:  # a job of an earlier sweep into the same folder
            continue
        d = json.loads(p.read_text())
        row = {"job": p.parent.name, **{k: v for k, v in d["config"]["learn"].items()
                                       if not isinstance(v, (list, dict))},
               "signal_weights": d["loss"]["signal_weights"], "inputs": ",".join(d["network"]["inputs"]),
               "epochs": d["epochs"]["run"], "best_epoch": d["epochs"]["best"],
               "val_loss": min([d["initial_loss"]["val_loss"]] + [e["val_loss"] for e in d["loss_per_epoch"]]),
               "train_s": d["wall_s"]["training"]}
        for m in ("vehicle", "hybrid"):
            for q in QUANTITIES:
                row[f"{m}.{q}_ratio"] = d["validation"]["ratio_to_rate_frozen_at_H"][m][q]
        rows.append(row)
    return pd.DataFrame(rows)


class ResidualSweep(SweepCallback):
    """A ``qr learn residual -m`` multirun: one MLflow parent run, ``OUTDIR/sweep.csv`` at the end (the job
    with the lowest validation loss tagged; never chosen on held-out flights: none are read)."""

    JOB = JOB

    def reset(self) -> None:
        super().reset()
        self._started = 0.0

    def on_multirun_start(self, config, **kwargs) -> None:
        if not self.mine(config):
            return
        self._started = time.time()
        out = Path(config.learn.out)
        out.mkdir(parents=True, exist_ok=True)
        name = f"residual {out.name}"
        params = {"sweep": name, "overrides": " ".join(config.hydra.overrides.task)}
        self._open(out, name, params, {"qr.kind": "residual"})

    def on_multirun_end(self, config, **kwargs) -> None:
        if self._cm is None:
            return
        from ..atomic import _write_marker, atomic_path

        out = Path(config.learn.out)
        runs = collect(out, self._started)
        with atomic_path(out / SWEEP_CSV) as tmp:
            runs.to_csv(tmp, index=False)
        # a qr output (Hydra's multirun.yaml too): a later sweep may replace them
        _write_marker(out, [SWEEP_CSV] + (["multirun.yaml"] if (out / "multirun.yaml").exists() else []),
                      "qr learn residual -m")
        if len(runs):
            best = runs.loc[runs["val_loss"].idxmin()]
            self._run.tags({"qr.best_job": best["job"]})
            self._run.metrics({"jobs": len(runs), "best_val_loss": best["val_loss"]})
        self._run.artifact(out / SWEEP_CSV)
        (out / PARENT_FILE).unlink(missing_ok=True)
        self._close(None)
