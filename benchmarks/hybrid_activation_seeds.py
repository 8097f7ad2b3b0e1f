"""How far the seed moves a fold's best validation loss, beside the tanh / relu difference (issue 33 part 3).

    .venv/bin/python benchmarks/hybrid_activation_seeds.py SET FOLD [--seeds 1 2] [--activations tanh relu]

Run it from a folder whose ``results/`` holds the full workflow's tree (a link is enough; nothing is
written).  The fold's training windows are made once, as ``benchmarks/hybrid_batch.py`` makes them (the
workflow's fold settings); then :func:`qr.residual_fit.train` runs for each activation and seed (the seed
draws the initial weights and the batches' order), with numba's pool launched first so that torch trains on
one thread (same numbers, faster: docs/learn.md "Batch size, and the threads torch really trains on").
Prints each run's best validation loss (the training side's validation flights only: the scored flights are
never opened) and best epoch, then per activation the mean and range over the seeds.
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hybrid_batch import _launch_numba_pool, fold_parts  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("set")
    ap.add_argument("fold")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--activations", nargs="+", default=["tanh", "relu"])
    a = ap.parse_args()
    from qr import residual_fit as rf

    _launch_numba_pool()
    log = lambda m: print(m, file=sys.stderr, flush=True)  # noqa: E731
    parts, split, settings, vehicle = fold_parts(a.set, a.fold, log)
    print(f"fold {a.set} {a.fold}: {sum(len(p.train) for p in parts)} training windows; load average "
          f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}", flush=True)
    best = {}
    for act in a.activations:
        for seed in a.seeds:
            tr = rf.train(replace(settings.learn, activation=act), vehicle, parts, seed, log)
            b = min([tr.initial["val_loss"]] + [e["val_loss"] for e in tr.epochs])
            best[act, seed] = b
            print(f"| {act} | seed {seed} | best validation loss {b:.4f} | epoch {tr.best_epoch} of {len(tr.epochs)} | "
                  f"{tr.wall_s:.0f} s |", flush=True)
    for act in a.activations:
        v = [best[act, s] for s in a.seeds]
        print(f"{act}: mean {sum(v) / len(v):.4f}, range {min(v):.4f}-{max(v):.4f} over seeds {a.seeds}")
    print(f"load average at the end {' '.join(f'{x:.1f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
