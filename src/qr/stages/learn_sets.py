"""The sweeps' and the workflow's glue of ``qr learn``: a multirun's MLflow parent run, progress bar and
``runs.csv`` (:class:`LearnSweep`, registered in ``conf/config.yaml`` as ``hydra.callbacks.learn_sweep``), the
sweep's best run (:func:`collect`, :func:`best`, :func:`copy_best`: rule ``learn_best``) and a flight set's
learning table (:func:`build_dataset`: rule ``learn_dataset``).

``LearnSweep`` acts only for multiruns of the stage (Hydra job name ``learn``); at the end it collects
``<out>/runs/*.json`` into ``<out>/runs.csv`` and logs the best run that does not leak its target.  If a job
fails, ``runs.csv`` is not written, so a workflow rule waiting for it fails too.
"""

from __future__ import annotations

import json
import math
import threading
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import QrInputError
from .sweep_callback import SweepCallback

if TYPE_CHECKING:  # pandas where a table is read or made
    import pandas as pd

RUNS_CSV = "runs.csv"


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
    JOB = "learn"

    def reset(self) -> None:
        super().reset()
        self._progress = None

    def on_multirun_start(self, config, **kwargs) -> None:
        if not self.mine(config):
            return
        out = _out(config)
        (out / "runs").mkdir(parents=True, exist_ok=True)
        for stale in (out / "runs").glob("*.json"):  # a rerun into the same directory starts clean
            stale.unlink()
        (out / RUNS_CSV).unlink(missing_ok=True)
        name = (config.get("sweep") or {}).get("name") or f"sweep {out.name}"
        params = {"sweep": name, "overrides": " ".join(config.hydra.overrides.task),
                  "sweeper_params": {str(k): str(v) for k, v in (config.hydra.sweeper.get("params") or {}).items()}}
        self._open(out, name, params)
        self._progress = _Progress(out / "runs", count_jobs(config), name)
        self._progress.start()

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
