"""Stage evaluate, the workflow's held-out folds: each fold (:class:`qr.holdout.Fold`) trains what it scores.

For one split of a set's flights (``evaluate.split``: a trajectory type, a time scale or the faster
flights held out), the training flights are diagnosed as rule ``evaluate_held_out`` diagnoses them (the
named effects, the refinement by the rollout's error, the learned torque remainder), the nominal,
extended, refined and hybrid vehicles are rolled out on the held-out flights with each window checked
against the training flights' envelope, and, where the fold asks for it, a residual is trained through
the rollout on the training flights (validation: whole trajectories of the training side) and scored on
the same held-out flights.  Writes ``OUT/training_diagnosis/``, ``OUT/held_out/`` (evaluation.json),
``OUT/residual/`` and ``OUT/learned/`` (with the residual), and ``OUT/fold.json`` (the split and what
each step took, s) last.
"""

from __future__ import annotations

import time
from pathlib import Path

FOLD_SCHEMA = "qr.fold/1"
RESIDUAL_LABEL = "hybrid (rollout-trained)"


def run_fold(flights, nis_files, vehicle, out, fold, overrides=(), single_overrides=(), residual_overrides=(),
             estimates=None, track: str | None = None, log=lambda m: None) -> dict:
    """Train and score one fold (``fold``: a :class:`qr.holdout.Fold`); ``overrides`` / ``single_overrides``:
    the training diagnosis's (as :func:`qr.stages.evaluate.evaluate_held_out`); ``residual_overrides``: those
    of ``qr learn residual``.  Returns ``fold.json``'s document."""
    from ..atomic import write_json
    from .evaluate import evaluate_held_out, evaluate_learned, held_out
    from .learn_residual_sets import train_held_out

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    flights = [str(f) for f in flights]
    a = held_out(flights, fold.split)
    seconds = {}
    t0 = time.perf_counter()
    log(f"fold {fold.name}: {a.held_out}; diagnosing {len(a.train)} flights, scoring {len(a.test)}")
    evaluate_held_out(flights, nis_files, vehicle, out / "training_diagnosis", out / "held_out", overrides,
                      single_overrides, track=track, estimates=estimates, split=fold.split)
    seconds["diagnose_and_evaluate"] = time.perf_counter() - t0
    if fold.hybrid:
        t0 = time.perf_counter()
        log(f"fold {fold.name}: training a residual through the rollout")
        train_held_out(flights, out / "training_diagnosis" / "extended_vehicle.yaml", out / "residual",
                       list(residual_overrides), reports=nis_files, estimates=estimates, split=fold.split,
                       track=False, log=log)
        seconds["residual"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        evaluate_learned(flights, nis_files, vehicle, [out / "residual" / "hybrid_vehicle.yaml"], [RESIDUAL_LABEL],
                         out / "learned", track=f"{track}:learned" if track else None, estimates=estimates,
                         split=fold.split)
        seconds["evaluate_residual"] = time.perf_counter() - t0
    doc = {"schema": FOLD_SCHEMA, "fold": fold.to_dict(), "split": a.to_dict(), "seconds": seconds,
           "evaluations": ["held_out"] + (["learned"] if fold.hybrid else [])}
    write_json(out / "fold.json", doc)
    return doc
