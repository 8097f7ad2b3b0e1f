"""Stage ``learn``: train and evaluate residual models (``qr learn`` = ``python -m qr.learn``, a Hydra app).

    qr learn learn.dataset=results/learn/brushless/dataset.parquet model=gpr learn.inputs=[v_b]
    python -m qr.learn -m model.layers=1,2,3 model.neurons=3,5 model.activation=linear,relu
    python -m qr.learn -m sweep=table_4_2 hydra/launcher=joblib2      # a named sweep, 2 processes

One run: learning table -> split (config group ``split``) -> fit (group
``model``) on the train part (the validation part for early stopping) ->
metrics on the test part -> ``<out>/models/<name>/`` (the saved model),
``<out>/runs/<name>.json`` (config, metrics, what training found) and an MLflow
run in experiment ``qr-learn``.  In a multirun every job is a child of one
parent run per sweep (:class:`LearnSweep`, below).  ``out`` defaults to Hydra's run or
sweep directory.

Metrics (test part): RMSE per axis and overall (the square root of the mean
over samples and axes), the nominal model's RMSE on the same samples (the
nominal model predicts no residual), their ratio (the thesis's "73.5 % of the
nominal model"), train time, and for a GP the 95 % band coverage.

Sweeps: ``LearnSweep`` is registered in ``conf/config.yaml`` as ``hydra.callbacks.learn_sweep``; it acts
only for multiruns of this stage (Hydra job name ``learn``).  At the start it opens the parent run and
writes its id to ``<out>/.mlflow_parent`` where every job (in this process or a joblib worker) finds it;
at the end it collects ``<out>/runs/*.json`` into ``<out>/runs.csv``, logs the best run that does not
leak its target, and closes the parent.  If a job fails, Hydra never calls the end hook: the parent is
then closed FAILED at exit and ``runs.csv`` is not written, so a workflow rule waiting for it fails too.
"""

from __future__ import annotations

import atexit
import json
import math
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .. import datasets
from ..errors import QrInputError

from .sweep_callback import SweepCallback

if TYPE_CHECKING:  # pandas where a table is read or made: `qr learn --help` needs none
    import pandas as pd

STAGE = "learn"
PARENT_FILE = ".mlflow_parent"
RUNS_CSV = "runs.csv"
LEARN_KEYS = ("target", "inputs", "dataset", "vehicle", "row")  # the group `learn` (conf/learn/), logged as params
LOGGED = ("split", "model", "seed")


def build_dataset(crossfit_files, names, vehicle_file, out) -> pd.DataFrame:
    """The learning table of a flight set from the filter stage's cross-fit files (their full-flight
    estimates: the states and matched rotor signals the diagnosis labels too), written to ``out``."""
    from .. import datasets
    from ..estimation.crossfit import Estimates
    from ..vehicle import load_vehicle

    states = {name: Estimates(path).full() for name, path in zip(names, crossfit_files)}
    table = datasets.build_table(states, load_vehicle(vehicle_file))
    datasets.write_table(table, out)
    return table


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
    row = cfg["learn"].get("row")
    if row is None:
        return cfg
    rows = (cfg.get("sweep") or {}).get("rows") or {}
    if row not in rows:
        raise QrInputError(None, f"learn.row={row} is not a row of sweep {(cfg.get('sweep') or {}).get('name')}",
                           f"use one of {sorted(rows)}")
    spec = dict(rows[row])
    out = {**cfg, "thesis": spec.pop("thesis", None),
           "thesis_nominal": (cfg.get("sweep") or {}).get("nominal_thesis")}
    model = dict(spec.pop("model", {}) or {})
    if model.get("kind", cfg["model"]["kind"]) != cfg["model"]["kind"]:
        raise QrInputError(None, f"sweep row {row} switches the model kind", "select the kind with the sweep's model")
    out["model"] = {**cfg["model"], **model}
    out["learn"] = {**cfg["learn"], **{key: spec.pop(key) for key in ("inputs", "target") if key in spec}}
    if spec:
        raise QrInputError(None, f"sweep row {row} has unknown key(s) {sorted(spec)}",
                           "rows set inputs, target, model and thesis")
    return out


def run(cfg: dict, out, name: str = "run", parent_id: str | None = None) -> dict:
    """One training run from a plain config; returns the run record (also written as JSON)."""
    from .. import models, tracking
    from ..atomic import MARKER, plain, write_json

    cfg = apply_row(cfg)
    learn = cfg["learn"]
    target = datasets.check_target(learn["target"])
    inputs = datasets.check_inputs(learn["inputs"])
    out = Path(out)
    logged = {**{k: learn.get(k) for k in LEARN_KEYS}, **{k: cfg.get(k) for k in LOGGED}}
    logged["sweep"] = (cfg.get("sweep") or {}).get("name")
    tags = {"qr.run": name}
    if parent_id:
        tags["mlflow.parentRunId"] = parent_id
    table = datasets.read_table(learn["dataset"], learn.get("vehicle"))  # wrong: one line, before MLflow
    with tracking.run(STAGE, name, config=logged, inputs=[learn["dataset"]], tags=tags) as tracked:
        tracked.dataset(learn["dataset"], table)
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
        record = {"name": name, "row": learn.get("row"), "sweep": logged["sweep"], "kind": model.kind,
                  "target": target, "inputs": inputs, "leaks_target": leaks, "model": model.cfg,
                  "split": cfg["split"], "seed": cfg.get("seed"), "thesis": cfg.get("thesis"),
                  "thesis_nominal": cfg.get("thesis_nominal"),
                  "dataset": str(learn["dataset"]), "metrics": metrics, "info": model.info,
                  "windows": sp.windows, "model_dir": str(model_dir)}
        run_json = out / "runs" / f"{name}.json"
        write_json(run_json, plain(record))
        tracked.tags({"qr.leaks_target": str(leaks).lower(), "qr.kind": model.kind, "qr.target": target})
        tracked.metrics(metrics)
        tracked.describe(outcome(record))
        if model.kind == "gpr":
            tracked.metrics(_hyper_metrics(model.info["hyperparameters"], target))
        for f in sorted(Path(model_dir).iterdir()):
            if f.name != MARKER:  # qr's own bookkeeping, not part of the model
                tracked.artifact(f, "qr_model")
        _log_mlflow_model(tracked, model, X[sp.train][:5])
        tracked.artifact(run_json)
    return record


def _log_mlflow_model(tracked, model, X_example) -> None:
    """The model in MLflow's own flavor (``pytorch`` for the ANN, ``sklearn`` for linear and GP) with its
    signature and an input example: ``mlflow.pyfunc.load_model("runs:/<id>/model")`` predicts in
    physical units, as qr's saved model does (``qr_model/``)."""
    from .. import __version__

    flavor, obj = model.mlflow_flavor()
    options = {}
    if flavor == "pytorch":
        import torch

        requirements = [f"torch=={torch.__version__.split('+')[0]}"]
    else:
        import pandas as pd
        import sklearn

        requirements = [f"scikit-learn=={sklearn.__version__}"] + ([f"qr=={__version__}"] if model.kind == "gpr" else [])
        X_example = pd.DataFrame(X_example, columns=model.meta.get("feature_names"))
        if model.kind == "gpr":  # qr's own classes inside: skops (the default) would refuse to load them
            options["serialization_format"] = "cloudpickle"
    tracked.model(flavor, obj, X_example, model.predict(np.asarray(X_example, dtype=float)), requirements,
                  **options)


def _hyper_metrics(hp, target) -> dict:
    out = {}
    for j, rows in enumerate(hp):
        for r in rows:
            key = r["name"].replace(" ", "_").replace("(", "").replace(")", "").replace("^", "")
            out[f"hp.{target}.{'xyz'[j]}.{key}"] = r["trained"]
    return out




def job_name(cfg: dict, hydra_cfg=None) -> str:
    row = cfg["learn"].get("row")
    if row is not None:
        return f"row{int(row):02d}"
    if hydra_cfg is not None and hydra_cfg.mode.name == "MULTIRUN":
        return f"job{int(hydra_cfg.job.num):03d}"
    return "run"


def out_dir(cfg: dict, hydra_cfg) -> Path:
    """``learn.out`` if set, else Hydra's sweep directory (multirun) or run directory."""
    if cfg["learn"].get("out"):
        return Path(cfg["learn"]["out"])
    return Path(hydra_cfg.sweep.dir if hydra_cfg.mode.name == "MULTIRUN" else hydra_cfg.run.dir)


def _main(cfg) -> float:
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf

    hc = HydraConfig.get()
    plain = OmegaConf.to_container(cfg, resolve=True)
    out = out_dir(plain, hc)
    parent = out / PARENT_FILE
    parent_id = parent.read_text().strip() if hc.mode.name == "MULTIRUN" and parent.exists() else None
    record = run(plain, out, job_name(plain, hc), parent_id)
    m = record["metrics"]
    sweep = hc.mode.name == "MULTIRUN"  # a job's line: its own settings, on a line of its own beside the bar
    lead = f"\n{record['name']} ({' '.join(hc.overrides.task)})" if sweep else record["name"]
    print(f"{lead}: {outcome(record)}, {m['train_time_s']:.2f} s", file=sys.stderr)
    return m["rmse"]


def outcome(record: dict) -> str:
    """A run's result in words, from its numbers (its line on the terminal, its MLflow description)."""
    m = record["metrics"]
    return (f"{record['kind']} {record['inputs']} -> {record['target']}: test RMSE {m['rmse']:.4g} "
            f"({100 * m['ratio']:.1f} % of nominal {m['nominal_rmse']:.4g})"
            + (", LEAKS TARGET" if record["leaks_target"] else ""))


def _precheck(cfg: dict) -> None:
    """What a run needs, checked before anything is written: a known target and inputs, a learning table
    (or state table) that exists."""
    datasets.check_target(cfg["learn"]["target"])
    datasets.check_inputs(cfg["learn"]["inputs"])
    datasets.check_dataset(cfg["learn"]["dataset"])


def main() -> None:
    """``qr learn`` / ``python -m qr.learn`` (``python -m qr.train``, the thesis-era name)."""
    from ..config import hydra_app

    hydra_app("learn", _main, _precheck)



# ---- sweeps: one MLflow parent run per Hydra multirun, a progress bar, runs.csv ----------

def collect(out) -> pd.DataFrame:
    """One row per run record in ``<out>/runs/*.json`` (row order, then name)."""
    import pandas as pd

    rows = []
    for p in sorted(Path(out, "runs").glob("*.json")):
        r = json.loads(p.read_text())
        m = r["model"]
        rows.append({
            "name": r["name"], "row": r.get("row"), "kind": r["kind"], "target": r["target"],
            "inputs": ",".join(r["inputs"]), "leaks_target": bool(r["leaks_target"]),
            "layers": m.get("layers"), "neurons": m.get("neurons"), "activation": m.get("activation"),
            "kernel": m.get("kernel"), "mean": m.get("mean"),
            **{k: v for k, v in r["metrics"].items()}, "thesis": r.get("thesis"),
            "thesis_nominal": r.get("thesis_nominal"), "model_dir": r["model_dir"],
        })
    df = pd.DataFrame(rows)
    if len(df) and df["row"].notna().any():
        df = df.sort_values(["row", "name"], kind="stable").reset_index(drop=True)
    return df


def best(runs: pd.DataFrame) -> pd.Series | None:
    """The lowest test RMSE among runs that do not leak their target (never a leaking one)."""
    ok = runs[~runs["leaks_target"].astype(bool)] if len(runs) else runs
    return None if ok.empty else ok.loc[ok["rmse"].idxmin()]


def _is_learn(config) -> bool:
    try:
        return config.hydra.job.name == "learn"
    except Exception:
        return False


def _out(config) -> Path:
    return Path(config.learn.out) if config.learn.get("out") else Path(config.hydra.sweep.dir)


def count_jobs(config) -> int | None:
    """Jobs a basic-sweeper multirun will launch (sweeper params x command-line sweeps)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    try:
        params = config.hydra.sweeper.get("params") or {}
        args = [f"{k}={v}" for k, v in params.items()] + list(config.hydra.overrides.task)
        n = 1
        for o in OverridesParser.create().parse_overrides(args):
            if o.is_sweep_override():
                n *= len(list(o.sweep_string_iterator()))
        return n
    except Exception:  # a sweep kind we cannot count (e.g. glob): bar without total
        return None


class _Progress(threading.Thread):
    """A tqdm bar counting finished jobs (their run records) while the launcher runs."""

    def __init__(self, runs_dir: Path, total: int | None, desc: str):
        super().__init__(daemon=True)
        self.runs_dir, self.total, self.desc = runs_dir, total, desc
        self.done = threading.Event()

    def run(self):
        from tqdm import tqdm

        with tqdm(total=self.total, desc=self.desc, unit="run") as bar:
            while True:
                stop = self.done.wait(0.5)
                n = len(list(self.runs_dir.glob("*.json"))) if self.runs_dir.exists() else 0
                if n != bar.n:
                    bar.update(n - bar.n)
                if stop:
                    break


class LearnSweep(SweepCallback):
    def reset(self) -> None:
        super().reset()
        self._run = self._progress = None

    def on_multirun_start(self, config, **kwargs) -> None:
        if not _is_learn(config):
            return
        from .. import tracking
        from ..atomic import write_text

        out = _out(config)
        (out / "runs").mkdir(parents=True, exist_ok=True)
        for stale in (out / "runs").glob("*.json"):  # a rerun into the same directory starts clean
            stale.unlink()
        (out / RUNS_CSV).unlink(missing_ok=True)
        name = (config.get("sweep") or {}).get("name") or f"sweep {out.name}"
        params = {"sweep": name, "overrides": " ".join(config.hydra.overrides.task),
                  "sweeper_params": {str(k): str(v) for k, v in (config.hydra.sweeper.get("params") or {}).items()}}
        self._cm = tracking.run("learn", name, config=params, tags={"qr.sweep": name, "qr.parent": "true"})
        self._run = self._cm.__enter__()
        write_text(out / PARENT_FILE, self._run.id + "\n")  # (a reader never finds it empty)
        self._progress = _Progress(out / "runs", count_jobs(config), name)
        self._progress.start()
        atexit.register(self._close, RuntimeError("a job of the sweep failed"))

    def on_multirun_end(self, config, **kwargs) -> None:
        if self._cm is None:
            return
        import pandas as pd

        from ..atomic import atomic_path

        self._stop_progress()
        out = _out(config)
        runs = collect(out)
        with atomic_path(out / RUNS_CSV) as tmp:
            runs.to_csv(tmp, index=False)
        b = best(runs)
        metrics = {"runs": len(runs)}
        if b is not None:
            metrics.update({"best_rmse": b["rmse"], "best_ratio": b["ratio"],
                            "best_row": float(b["row"]) if pd.notna(b["row"]) else math.nan})
            self._run.tags({"qr.best_run": b["name"]})
            self._run.describe(f"{len(runs)} runs; the best that does not leak its target: {b['name']}, test RMSE "
                               f"{b['rmse']:.4g} ({100 * b['ratio']:.1f} % of the nominal model's)")
        self._run.metrics(metrics)
        self._run.artifact(out / RUNS_CSV)
        self._close(None)

    def _stop_progress(self):
        if self._progress is not None:
            self._progress.done.set()
            self._progress.join()
            self._progress = None

    def _close(self, exc) -> None:
        if self._cm is not None:
            self._stop_progress()
        super()._close(exc)


def copy_best(runs_csv, dest) -> pd.Series:
    """Copy the saved model of the sweep's best non-leaking run to ``dest`` (replaced atomically)."""
    import shutil

    import pandas as pd

    from ..atomic import atomic_dir
    
    b = best(pd.read_csv(runs_csv))
    if b is None:
        raise QrInputError(runs_csv, "every run of the sweep leaks its target", "add rows without a_b / alpha")
    with atomic_dir(dest) as tmp:
        for f in Path(b["model_dir"]).iterdir():
            shutil.copy2(f, tmp / f.name)
    return b


if __name__ == "__main__":
    main()
