"""Train and evaluate one residual model: ``python -m qr.train`` (a Hydra app).

    python -m qr.train dataset=results/learn/brushless/dataset.parquet model=gpr inputs=[v_b]
    python -m qr.train -m model.layers=1,2,3 model.neurons=3,5 model.activation=linear,relu
    python -m qr.train -m sweep=table_4_2 hydra/launcher=joblib2      # a named sweep, 2 processes

One run: learning table -> split (config group ``split``) -> fit (group
``model``) on the train part (the validation part for early stopping) ->
metrics on the test part -> ``<out>/models/<name>/`` (the saved model),
``<out>/runs/<name>.json`` (config, metrics, what training found) and an MLflow
run in experiment ``qr-learn``.  In a multirun every job is a child of one
parent run per sweep (:mod:`qr.sweeps`).  ``out`` defaults to Hydra's run or
sweep directory.

Metrics (test part): RMSE per axis and overall (the square root of the mean
over samples and axes), the nominal model's RMSE on the same samples (the
nominal model predicts no residual), their ratio (the thesis's "73.5 % of the
nominal model"), train time, and for a GP the 95 % band coverage.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from . import datasets
from .errors import QrInputError

STAGE = "learn"
LOGGED = ("target", "inputs", "dataset", "split", "model", "seed", "row")


def evaluate(model, X, y, target: str) -> dict:
    """Test metrics of ``model`` on ``(X, y)`` (see the module doc)."""
    axes = [f"{target[0]}_{c}" if target == "f_a" else f"tau_{c}" for c in datasets.TARGETS[target]]
    if model.kind == "gpr":
        pred, std = model.predict(X, return_std=True)
    else:
        pred, std = model.predict(X), None
    err = y - pred
    out = {"rmse": _rms(err), "nominal_rmse": _rms(y)}
    out["ratio"] = out["rmse"] / out["nominal_rmse"]
    for j, a in enumerate(axes):
        out[f"rmse_{a}"] = _rms(err[:, j])
        out[f"nominal_rmse_{a}"] = _rms(y[:, j])
        out[f"ratio_{a}"] = out[f"rmse_{a}"] / out[f"nominal_rmse_{a}"]
    if std is not None:
        inside = np.abs(err) <= 1.959964 * std
        out["coverage95"] = float(inside.mean())
        for j, a in enumerate(axes):
            out[f"coverage95_{a}"] = float(inside[:, j].mean())
    return out


def _rms(e) -> float:
    return float(np.sqrt(np.mean(np.square(e))))


def apply_row(cfg: dict) -> dict:
    """A named sweep's row (``sweep.rows[row]``: inputs, target, model options) applied to the config."""
    row = cfg.get("row")
    if row is None:
        return cfg
    rows = (cfg.get("sweep") or {}).get("rows") or {}
    if row not in rows:
        raise QrInputError(None, f"row={row} is not a row of sweep {(cfg.get('sweep') or {}).get('name')}",
                           f"use one of {sorted(rows)}")
    spec = dict(rows[row])
    out = {**cfg, "thesis": spec.pop("thesis", None),
           "thesis_nominal": (cfg.get("sweep") or {}).get("nominal_thesis")}
    model = dict(spec.pop("model", {}) or {})
    if model.get("kind", cfg["model"]["kind"]) != cfg["model"]["kind"]:
        raise QrInputError(None, f"sweep row {row} switches the model kind", "select the kind with the sweep's model")
    out["model"] = {**cfg["model"], **model}
    for key in ("inputs", "target"):
        if key in spec:
            out[key] = spec.pop(key)
    if spec:
        raise QrInputError(None, f"sweep row {row} has unknown key(s) {sorted(spec)}",
                           "rows set inputs, target, model and thesis")
    return out


def run(cfg: dict, out, name: str = "run", parent_id: str | None = None) -> dict:
    """One training run from a plain config; returns the run record (also written as JSON)."""
    from . import models, tracking
    from .atomic import MARKER, write_json

    cfg = apply_row(cfg)
    target = datasets.check_target(cfg["target"])
    inputs = datasets.check_inputs(cfg["inputs"])
    out = Path(out)
    logged = {k: cfg.get(k) for k in LOGGED}
    logged["sweep"] = (cfg.get("sweep") or {}).get("name")
    tags = {"qr.run": name}
    if parent_id:
        tags["mlflow.parentRunId"] = parent_id
    with tracking.run(STAGE, name, config=logged, inputs=[cfg["dataset"]], tags=tags) as tracked:
        table = datasets.read_table(cfg["dataset"])
        tracked.dataset(cfg["dataset"], table)
        X, y = datasets.xy(table, inputs, target)
        sp = datasets.split(table, cfg["split"])
        model_cfg = {k: v for k, v in cfg["model"].items() if k != "kind"}
        leaks = datasets.leaks_target(target, inputs)
        meta = {"inputs": inputs, "target": target, "feature_names": datasets.columns(inputs), "leaks_target": leaks}
        models.prepare(cfg["model"]["kind"])
        t0 = time.perf_counter()
        model = models.fit(cfg["model"]["kind"], X[sp.train], y[sp.train], model_cfg,
                           val=(X[sp.val], y[sp.val]), meta=meta)
        train_time = time.perf_counter() - t0
        metrics = evaluate(model, X[sp.test], y[sp.test], target)
        metrics.update({"train_time_s": train_time, "train_rmse": _rms(y[sp.train] - model.predict(X[sp.train])),
                        "n_train": len(sp.train), "n_val": len(sp.val), "n_test": len(sp.test)})
        model_dir = model.save(out / "models" / name)
        record = {"name": name, "row": cfg.get("row"), "sweep": logged["sweep"], "kind": model.kind,
                  "target": target, "inputs": inputs, "leaks_target": leaks, "model": model.cfg,
                  "split": cfg["split"], "seed": cfg.get("seed"), "thesis": cfg.get("thesis"),
                  "thesis_nominal": cfg.get("thesis_nominal"),
                  "dataset": str(cfg["dataset"]), "metrics": metrics, "info": model.info,
                  "windows": sp.windows, "model_dir": str(model_dir)}
        run_json = out / "runs" / f"{name}.json"
        write_json(run_json, _jsonable(record))
        tracked.tags({"qr.leaks_target": str(leaks).lower(), "qr.kind": model.kind, "qr.target": target})
        tracked.metrics(metrics)
        if model.kind == "gpr":
            tracked.metrics(_hyper_metrics(model.info["hyperparameters"], target))
        for f in sorted(Path(model_dir).iterdir()):
            if f.name != MARKER:  # qr's own bookkeeping, not part of the model
                tracked.artifact(f, "model")
        tracked.artifact(run_json)
    return record


def _hyper_metrics(hp, target) -> dict:
    out = {}
    for j, rows in enumerate(hp):
        for r in rows:
            key = r["name"].replace(" ", "_").replace("(", "").replace(")", "").replace("^", "")
            out[f"hp.{target}.{'xyz'[j]}.{key}"] = r["trained"]
    return out


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    return o


def job_name(cfg: dict, hydra_cfg=None) -> str:
    if cfg.get("row") is not None:
        return f"row{int(cfg['row']):02d}"
    if hydra_cfg is not None and hydra_cfg.mode.name == "MULTIRUN":
        return f"job{int(hydra_cfg.job.num):03d}"
    return "run"


def out_dir(cfg: dict, hydra_cfg) -> Path:
    """``out`` if set, else Hydra's sweep directory (multirun) or run directory."""
    if cfg.get("out"):
        return Path(cfg["out"])
    return Path(hydra_cfg.sweep.dir if hydra_cfg.mode.name == "MULTIRUN" else hydra_cfg.run.dir)


def _main(cfg) -> float:
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf

    from .sweeps import PARENT_FILE

    hc = HydraConfig.get()
    plain = OmegaConf.to_container(cfg, resolve=True)
    out = out_dir(plain, hc)
    parent = out / PARENT_FILE
    parent_id = parent.read_text().strip() if hc.mode.name == "MULTIRUN" and parent.exists() else None
    try:
        record = run(plain, out, job_name(plain, hc), parent_id)
    except QrInputError as e:
        print(f"qr.train: error: {e}", file=sys.stderr)
        sys.exit(2)
    m = record["metrics"]
    print(f"{record['name']}: {record['kind']} {record['inputs']} -> {record['target']}: test RMSE {m['rmse']:.4g} "
          f"({100 * m['ratio']:.1f} % of nominal {m['nominal_rmse']:.4g}), "
          f"{'LEAKS TARGET, ' if record['leaks_target'] else ''}{m['train_time_s']:.2f} s", file=sys.stderr)
    return m["rmse"]


def main() -> None:
    import hydra

    from .config import CONF_DIR

    hydra.main(config_path=CONF_DIR, config_name="config", version_base="1.3")(_main)()


if __name__ == "__main__":
    main()
