"""Residual models behind one interface.

    model = qr.models.fit("ann", X, y, cfg, val=(X_val, y_val), meta={...})
    y_hat = model.predict(X)
    model.save(directory)
    model = qr.models.load(directory)

Kinds: ``ann`` (torch MLP), ``linear`` (closed-form ridge), ``gpr``
(scikit-learn GP per axis).  ``cfg`` is the ``model`` config group (its
``kind`` key, if any, is ignored).  ``meta`` records what the model was
trained on (``inputs``, ``target``, ``feature_names``, ``leaks_target``) and is
saved with it; :func:`qr.datasets.features` rebuilds ``X`` from
``model.inputs``.  Affine models (``linear``, an ``ann`` with linear
activations) expose ``collapse() -> (W, b)`` in input units.
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path

from ..errors import QrInputError
from .base import SCHEMA, Model


# kind -> (module, class): a kind's module is imported when it is used (the GPR's scikit-learn and the
# ANN's torch take seconds to import; qr diagnose fits only the linear one)
KINDS = {"ann": ("ann", "ANN"), "linear": ("linear", "Ridge"), "gpr": ("gpr", "GPR")}


def model_class(kind: str):
    if kind not in KINDS:
        raise QrInputError(None, f"unknown model kind '{kind}'", f"use one of {', '.join(KINDS)}")
    module, name = KINDS[kind]
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)


def prepare(kind: str) -> None:
    """Pay a kind's one-time import costs now (so a timed fit measures training only)."""
    cls = model_class(kind)
    getattr(cls, "prepare", lambda: None)()


def fit(kind: str, X, y, cfg=None, val=None, meta: dict | None = None) -> Model:
    """Train a model of ``kind`` on ``(X, y)``; ``val`` = ``(X_val, y_val)`` for early stopping (ANN)."""
    cls = model_class(kind)
    return cls(cls.config(cfg), meta).fit(X, y, val=val)


def load(path) -> Model:
    """A model saved with ``model.save(path)``."""
    path = Path(path)
    doc_path = path / "model.json"
    if not doc_path.exists():
        raise QrInputError(path, "no model.json: not a saved qr model", "give a directory written by model.save()")
    doc = json.loads(doc_path.read_text())
    if doc.get("schema") != SCHEMA:
        raise QrInputError(path, f"model schema {doc.get('schema')!r}, expected {SCHEMA!r}", "retrain the model")
    return model_class(doc["kind"])._load(path, doc)


__all__ = ["Model", "fit", "load", "model_class", "prepare"]
