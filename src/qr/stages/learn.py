"""Stage ``learn``: train and evaluate residual models (``qr learn`` = ``python -m qr.learn``, a Hydra app).

    qr learn learn.dataset=results/learn/brushless/dataset.parquet model=gpr learn.inputs=[v_b]
    python -m qr.learn -m model.layers=1,2,3 model.neurons=3,5 model.activation=linear,relu
    python -m qr.learn -m sweep=table_4_2 hydra/launcher=joblib2      # a named sweep, 2 processes

One run (:func:`run_learn`): reads the learning table, trains and scores (:func:`qr.models.training.run`),
writes ``<out>/models/<name>/`` (the saved model) and ``<out>/runs/<name>.json`` (config, metrics, what
training found) and tracks an MLflow run in experiment ``qr-learn``.  In a multirun every job is a child
of one parent run per sweep (:class:`qr.stages.learn_sets.LearnSweep`, which also writes ``runs.csv``).
``out`` defaults to Hydra's run or sweep directory.
"""

from __future__ import annotations

import sys
from pathlib import Path

from ..models.training import Training, apply_row, check, document, mlflow_model, outcome, run, tracked_metrics
from .sweep_callback import parent_id

STAGE = "learn"
LEARN_KEYS = ("target", "inputs", "dataset", "vehicle", "row")  # the group `learn` (conf/learn/), logged as params
LOGGED = ("split", "model", "seed")


def run_learn(cfg: dict, out, name: str = "run", parent_id: str | None = None) -> Training:
    """One training run from a plain config into ``out`` (its record ``runs/<name>.json``, its model
    ``models/<name>/``)."""
    from .. import datasets, tracking
    from ..atomic import MARKER, plain, write_json

    cfg = apply_row(cfg)
    learn, out = cfg["learn"], Path(out)
    logged = {**{k: learn.get(k) for k in LEARN_KEYS}, **{k: cfg.get(k) for k in LOGGED},
              "sweep": (cfg.get("sweep") or {}).get("name")}
    tags = {"qr.run": name, **({"mlflow.parentRunId": parent_id} if parent_id else {})}
    table = datasets.read_table(learn["dataset"], learn.get("vehicle"))  # wrong: one line, before MLflow
    with tracking.run(STAGE, name, config=logged, inputs=[learn["dataset"]], tags=tags) as tracked:
        tracked.dataset(learn["dataset"], table)
        training = run(cfg, table, name)
        model_dir = training.model.save(out / "models" / name)
        write_json(out / "runs" / f"{name}.json", plain(document(training, model_dir)))
        tracked.tags({"qr.leaks_target": str(training.leaks_target).lower(), "qr.kind": training.model.kind,
                      "qr.target": training.target})
        tracked.metrics(tracked_metrics(training))
        tracked.describe(outcome(training))
        for f in sorted(Path(model_dir).iterdir()):
            if f.name != MARKER:  # qr's own bookkeeping, not part of the model
                tracked.artifact(f, "qr_model")
        *args, options = mlflow_model(training)
        tracked.model(*args, **options)
        tracked.artifact(out / "runs" / f"{name}.json")
    return training


def job_name(cfg: dict, multirun_job: int | None = None) -> str:
    """``rowNN`` (a named sweep's row), ``jobNNN`` (a multirun's job) or ``run``."""
    row = cfg["learn"].get("row")
    return f"row{int(row):02d}" if row is not None else "run" if multirun_job is None else f"job{multirun_job:03d}"


def _main(cfg) -> float:
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf

    hc = HydraConfig.get()
    plain, sweep = OmegaConf.to_container(cfg, resolve=True), hc.mode.name == "MULTIRUN"
    out = Path(plain["learn"].get("out") or (hc.sweep.dir if sweep else hc.run.dir))  # learn.out, else Hydra's
    t = run_learn(plain, out, job_name(plain, int(hc.job.num) if sweep else None), parent_id(out) if sweep else None)
    lead = f"\n{t.name} ({' '.join(hc.overrides.task)})" if sweep else t.name  # a job's own line, beside the bar
    print(f"{lead}: {outcome(t)}, {t.scores.train_time_s:.2f} s", file=sys.stderr)
    return t.scores.rmse


def main() -> None:
    """``qr learn`` / ``python -m qr.learn`` (``python -m qr.train``, the thesis-era name)."""
    from ..config import hydra_app

    hydra_app("learn", _main, check)


if __name__ == "__main__":
    main()
