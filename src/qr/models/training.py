"""One training run of ``qr learn``: :func:`run` (a config and a learning table) -> :class:`Training`.

The learning table -> split (config group ``split``) -> fit (group ``model``) on the train part (the
validation part for early stopping) -> scores on the test part.  Scores (:class:`Scores`): RMSE per axis
and overall (the square root of the mean over samples and axes), the nominal model's RMSE on the same
samples (the nominal model predicts no residual), their ratio (the thesis's "73.5 % of the nominal
model"), train time, and for a GP the 95 % band coverage.  :func:`document` is the run record
(``runs/<name>.json``), :func:`outcome` its sentence; the stage (:mod:`qr.stages.learn`) reads, saves,
writes and tracks.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .. import datasets
from ..config import Group
from ..errors import QrInputError
from . import Model


@dataclass(frozen=True)
class AxisScores:
    axis: str  # f_x .. f_z or tau_x .. tau_z
    rmse: float
    nominal_rmse: float
    coverage95: float | None  # a GP's: the share of test samples inside its 95 % band

    @property
    def ratio(self) -> float:
        return self.rmse / self.nominal_rmse


@dataclass(frozen=True)
class Scores:
    """The test part's scores, and what the training took."""

    rmse: float
    nominal_rmse: float
    axes: tuple[AxisScores, ...]
    coverage95: float | None
    train_time_s: float
    train_rmse: float
    n_train: int
    n_val: int
    n_test: int

    @property
    def ratio(self) -> float:
        return self.rmse / self.nominal_rmse

    def to_dict(self) -> dict:
        out = {"rmse": self.rmse, "nominal_rmse": self.nominal_rmse, "ratio": self.ratio}
        for a in self.axes:
            out |= {f"rmse_{a.axis}": a.rmse, f"nominal_rmse_{a.axis}": a.nominal_rmse, f"ratio_{a.axis}": a.ratio}
        if self.coverage95 is not None:
            out["coverage95"] = self.coverage95
            out |= {f"coverage95_{a.axis}": a.coverage95 for a in self.axes}
        return out | {"train_time_s": self.train_time_s, "train_rmse": self.train_rmse, "n_train": self.n_train,
                      "n_val": self.n_val, "n_test": self.n_test}


@dataclass(frozen=True)
class Training:
    """One trained model and its scores, with the settings it was trained with."""

    name: str
    row: int | None  # the named sweep's row, or None
    sweep: str | None
    target: str
    inputs: tuple[str, ...]
    leaks_target: bool
    model: Model  # fitted (kind, cfg, info)
    split: Group  # the split group as given
    seed: int | None
    thesis: float | None  # the thesis's RMSE of the row (a named sweep's), its nominal model's
    thesis_nominal: float | None
    dataset: str
    scores: Scores
    windows: Mapping[str, Mapping[str, list[float]]]  # part -> {flight: [t_start, t_end]} (provenance)
    example: np.ndarray  # the first training inputs (MLflow's input example)


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


def check(cfg: dict) -> None:
    """What a run needs, checked before anything is written: a known target and inputs, a learning table
    (or state table) that exists."""
    datasets.check_target(cfg["learn"]["target"])
    datasets.check_inputs(cfg["learn"]["inputs"])
    datasets.check_dataset(cfg["learn"]["dataset"])


def run(cfg: dict, table, name: str = "run") -> Training:
    """Train ``cfg``'s model (a named sweep's row applied: :func:`apply_row`) on ``table`` and score it."""
    from .. import models

    learn = cfg["learn"]
    target = datasets.check_target(learn["target"])
    inputs = datasets.check_inputs(learn["inputs"])
    X, y = datasets.xy(table, inputs, target)
    sp = datasets.split(table, cfg["split"])
    kind = cfg["model"]["kind"]
    leaks = datasets.leaks_target(target, inputs)
    meta = {"inputs": inputs, "target": target, "feature_names": datasets.columns(inputs), "leaks_target": leaks}
    models.prepare(kind)
    t0 = time.perf_counter()
    model = models.fit(kind, X[sp.train], y[sp.train], {k: v for k, v in cfg["model"].items() if k != "kind"},
                       val=(X[sp.val], y[sp.val]), meta=meta)
    train_time = time.perf_counter() - t0
    scores = _scores(model, X[sp.test], y[sp.test], target, train_time_s=train_time,
                     train_rmse=_rms(y[sp.train] - model.predict(X[sp.train])), n_train=len(sp.train),
                     n_val=len(sp.val), n_test=len(sp.test))
    return Training(name, learn.get("row"), (cfg.get("sweep") or {}).get("name"), target, tuple(inputs), leaks, model,
                    cfg["split"], cfg.get("seed"), cfg.get("thesis"), cfg.get("thesis_nominal"), str(learn["dataset"]),
                    scores, sp.windows, X[sp.train][:5])


def _scores(model, X, y, target: str, **training) -> Scores:
    """The scores of ``model`` on ``(X, y)`` (see the module doc)."""
    axes = [f"{target[0]}_{c}" if target == "f_a" else f"tau_{c}" for c in datasets.TARGETS[target]]
    if model.kind == "gpr":
        pred, std = model.predict(X, return_std=True)
    else:
        pred, std = model.predict(X), None
    err = y - pred
    inside = None if std is None else np.abs(err) <= 1.959964 * std
    return Scores(_rms(err), _rms(y), tuple(
        AxisScores(a, _rms(err[:, j]), _rms(y[:, j]), None if inside is None else float(inside[:, j].mean()))
        for j, a in enumerate(axes)), None if inside is None else float(inside.mean()), **training)


def _rms(e) -> float:
    return float(np.sqrt(np.mean(np.square(e))))


def document(t: Training, model_dir) -> dict:
    """The run record (``runs/<name>.json``) of ``t``, its model saved in ``model_dir``."""
    return {"name": t.name, "row": t.row, "sweep": t.sweep, "kind": t.model.kind, "target": t.target,
            "inputs": list(t.inputs), "leaks_target": t.leaks_target, "model": t.model.cfg, "split": t.split,
            "seed": t.seed, "thesis": t.thesis, "thesis_nominal": t.thesis_nominal, "dataset": t.dataset,
            "metrics": t.scores.to_dict(), "info": t.model.info, "windows": t.windows, "model_dir": str(model_dir)}


def outcome(t: Training) -> str:
    """A run's result in words, from its numbers (its line on the terminal, its MLflow description)."""
    s = t.scores
    return (f"{t.model.kind} {list(t.inputs)} -> {t.target}: test RMSE {s.rmse:.4g} "
            f"({100 * s.ratio:.1f} % of nominal {s.nominal_rmse:.4g})" + (", LEAKS TARGET" if t.leaks_target else ""))


def tracked_metrics(t: Training) -> dict:
    """The run's MLflow metrics: the scores, and a GP's trained hyperparameters (``hp.<target>.<axis>.<name>``)."""
    out = t.scores.to_dict()
    if t.model.kind == "gpr":
        for j, rows in enumerate(t.model.info["hyperparameters"]):
            for r in rows:
                key = r["name"].replace(" ", "_").replace("(", "").replace(")", "").replace("^", "")
                out[f"hp.{t.target}.{'xyz'[j]}.{key}"] = r["trained"]
    return out


def mlflow_model(t: Training) -> tuple:
    """``Run.model``'s arguments for the model in MLflow's own flavor (``pytorch`` for the ANN, ``sklearn`` for
    linear and GP), its signature and input example: ``mlflow.pyfunc.load_model("runs:/<id>/model")`` predicts
    in physical units, as qr's saved model does (``qr_model/``).  (flavor, object, example, its prediction,
    requirements, save options)."""
    from .. import __version__

    model, X_example, options = t.model, t.example, {}
    flavor, obj = model.mlflow_flavor()
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
    return flavor, obj, X_example, model.predict(np.asarray(X_example, dtype=float)), requirements, options
