"""``evaluation.json`` (schema ``qr.evaluation/1``, docs/spec/evaluate.md) of a
:class:`qr.evaluate.evaluation.Evaluation`: the one writer of that document."""

from __future__ import annotations

import numpy as np

from ..envelope import QUANTITIES
from ..rollout import summary

SCHEMA = "qr.evaluation/1"


def document(e) -> dict:
    H, dt = e.settings.evaluate.horizon, e.steps
    doc = {
        "schema": SCHEMA,
        "flights": list(e.flights),
        "vehicles": [m.file for m in e.models],
        "dt": float(np.median(dt)),
        "dt_range": [float(dt.min()), float(dt.max())],
        "horizon": H,
        "config": {"evaluate": {**e.settings.given}, "filter": e.settings.filter},
        "labels": {m.key: m.label for m in e.models},
        "models": {k: summary(*v) for k, v in e.pooled.items()},
        "per_flight": {f: {"models": {k: summary(*v) for k, v in p.items()}} for f, p in e.per_flight.items()},
    }
    if e.split is not None:
        doc["split"] = e.split.to_dict()
    if e.envelope is not None:
        doc["envelope"] = envelope_block(e.envelope)
    if e.bands is not None:
        doc["bands"], doc["bands_none"] = e.bands.blocks(H)
    return doc


def envelope_block(ec) -> dict:
    """``envelope``: the training flights' extremes, and per scored flight and pooled the windows outside them."""
    outside = ec.outside
    n = sum(o.windows for o in outside.values())
    k = {q: sum(o.share_outside_by[q] * o.windows for o in outside.values() if o.windows) for q in QUANTITIES}
    m = sum(o.outside for o in outside.values())
    return {"trained_on": list(ec.trained_on), "limits": ec.envelope.to_dict(), "windows": n, "outside": m,
            "share_outside": m / n if n else None,
            "share_outside_by": {q: (round(k[q]) / n if n else None) for q in QUANTITIES},
            "per_flight": {f: o.record() for f, o in outside.items()}}
