"""What every residual model shares: config checking, scaling, metadata, the saved-model directory.

A saved model is a directory::

    model.json     {"schema": "qr.model/1", "kind", "config", "inputs", "target",
                    "feature_names", "leaks_target", "info"}
    <weights>      the kind's own file (weights.pt, weights.npz, gpr.npz)

``inputs`` and ``target`` let a caller rebuild the features with
``qr.datasets.features(signals, model.inputs)``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import QrInputError

SCHEMA = "qr.model/1"


def plain(cfg) -> dict:
    """A plain dict of a (possibly OmegaConf) config."""
    if cfg is None:
        return {}
    try:
        from omegaconf import DictConfig, OmegaConf

        if isinstance(cfg, DictConfig):
            return OmegaConf.to_container(cfg, resolve=True)
    except ImportError:  # pragma: no cover
        pass
    return dict(cfg)


class Scaler:
    """Per-column standardisation; constant columns keep scale 1."""

    def __init__(self, mean, std):
        self.mean = np.asarray(mean, dtype=float)
        self.std = np.asarray(std, dtype=float)

    @classmethod
    def fit(cls, a) -> "Scaler":
        a = np.asarray(a, dtype=float)
        std = a.std(axis=0)
        return cls(a.mean(axis=0), np.where(std > 1e-12 * (1 + np.abs(a.mean(axis=0))), std, 1.0))

    def __call__(self, a):
        return (np.asarray(a, dtype=float) - self.mean) / self.std

    def inverse(self, a):
        return np.asarray(a) * self.std + self.mean


class Model:
    """Base class: ``predict(X)``, ``save(dir)``; metadata says what it was trained on."""

    kind = "?"
    DEFAULTS: dict = {}

    def __init__(self, cfg: dict, meta: dict | None = None):
        self.cfg = cfg
        self.meta = dict(meta or {})
        self.info: dict = {}  # what training found (iterations, hyperparameters, ...)

    @classmethod
    def config(cls, cfg) -> dict:
        cfg = plain(cfg)
        cfg.pop("kind", None)
        bad = [k for k in cfg if k not in cls.DEFAULTS]
        if bad:
            raise QrInputError(None, f"model {cls.kind} has no option(s) {bad}",
                               f"its options are {', '.join(cls.DEFAULTS)}")
        return {**cls.DEFAULTS, **cfg}

    # metadata the simulation study needs
    @property
    def inputs(self) -> list[str]:
        return list(self.meta.get("inputs", []))

    @property
    def target(self) -> str | None:
        return self.meta.get("target")

    @property
    def leaks_target(self) -> bool:
        return bool(self.meta.get("leaks_target", False))

    def predict(self, X) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def save(self, path) -> Path:
        """Write the model directory atomically (an existing one is replaced)."""
        from ..atomic import atomic_dir

        path = Path(path)
        with atomic_dir(path) as tmp:
            self._save_weights(tmp)
            doc = {"schema": SCHEMA, "kind": self.kind, "config": self.cfg, **self.meta, "info": self.info}
            (tmp / "model.json").write_text(json.dumps(doc, indent=2, default=_json_default) + "\n")
        return path

    def _save_weights(self, path: Path) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def mlflow_flavor(self) -> tuple[str, object]:  # pragma: no cover - abstract
        """``(flavor, object)``: the model as MLflow's ``pytorch`` or ``sklearn`` flavor stores it,
        predicting what :meth:`predict` predicts, in the same units."""
        raise NotImplementedError

    @classmethod
    def _load(cls, path: Path, doc: dict) -> "Model":  # pragma: no cover - abstract
        raise NotImplementedError


def meta_of(doc: dict) -> dict:
    """The metadata part of a ``model.json``."""
    return {k: doc[k] for k in ("inputs", "target", "feature_names", "leaks_target") if k in doc}


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o)}")


def check_xy(X, y=None):
    X = np.asarray(X, dtype=float)
    if X.ndim != 2:
        raise QrInputError(None, f"model input has shape {X.shape}", "give X as (samples, features)")
    if y is not None:
        y = np.asarray(y, dtype=float)
        y = y[:, None] if y.ndim == 1 else y
        if len(y) != len(X):
            raise QrInputError(None, f"X has {len(X)} rows but y has {len(y)}", "give one label row per sample")
        if not (np.isfinite(X).all() and np.isfinite(y).all()):
            raise QrInputError(None, "training data contain NaN or inf", "drop non-finite rows first")
    return X, y
