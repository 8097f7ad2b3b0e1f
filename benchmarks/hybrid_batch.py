"""The rollout training's seconds per epoch and best validation loss against the batch size (issue 33).

    .venv/bin/python benchmarks/hybrid_batch.py [SET FOLD] [--batches 64 128 256] [--epochs N]

Run it from a folder whose ``results/`` holds the full workflow's tree (rule generalization_fold; a
symlink to a complete tree is enough: nothing is written under ``results/``, and nothing anywhere else
either).  Default fold: ``brushless speed-ts0.6-0.5`` (train 1.0–0.7, score 0.6–0.5).

The fold's training flights are read, filtered and cut into windows once, as the workflow's fold does
(its training diagnosis's vehicle, ``learn.keep_remainder=false``, the workflow's residual overrides:
``learn.stride=8``); then :func:`qr.residual_fit.train` runs once per setting on the same windows, same
seed: ``learn.batch`` = each of ``--batches`` with ``learn.lr`` unscaled (3e-3, the default) and, for
every batch but the first, scaled by sqrt(batch / first batch).  Only the training side's validation
flights are scored (the validation loss ``qr learn residual`` stops on); the fold's scored flights are
never opened.  Prints, per setting: epochs run, best epoch, best validation loss and its ratio to the
first setting's, wall seconds per epoch (mean / min), the process's CPU seconds per epoch (one torch
thread: less polluted by other jobs than the wall clock) and their ratio to the first's, training seconds.

Threads (``--threads``).  :func:`qr.residual_fit.train` sets torch to one thread, then its first compiled
rollout (:func:`qr.rollout.reference_mae`, numba ``parallel=True``) launches numba's OpenMP pool, which
sets the process's OpenMP thread count (shared with torch's libgomp) back to numba's (the cores): the
first training of a process then runs torch's element-wise ops on 2 OpenMP threads for all its epochs;
a later one keeps the one thread.  ``--threads as-is`` (default) shows what a process does today (each
setting in a fresh state is not possible in one process: only the first setting runs that way; give
``--again`` to see the first setting once more with one thread).  ``--threads one`` launches numba's pool
before the first training, so every setting trains on one thread.  The torch threads seen during each
setting's first epoch are printed.

The machine may be shared: the load average is printed; quote the figures "under load" unless it was quiet.
Each setting's epochs go to stderr as they come, so a run stopped early still says something.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import yaml


def fold_parts(set_name: str, fold_name: str, log):
    """The fold's training windows (:class:`qr.residual_fit.Piece` list), its settings and physical vehicle."""
    from qr import holdout
    from qr import residual_fit as rf
    from qr.flight import read_flight
    from qr.holdout import folds, held_out
    from qr.intake import read_reports
    from qr.pieces import rollout_pieces
    from qr.residual_training import Settings, check_flights
    from qr.rollout import windows
    from qr.stages.learn_residual import compose
    from qr.vehicle import load_vehicle, vehicle_from_dict

    wf = yaml.safe_load(Path("conf/workflow.yaml").read_text())
    data_file = wf["data"]
    data = yaml.safe_load(Path(data_file).read_text())
    names = data["sets"][set_name]["flights"]
    specs = data["workflow"]["generalization"]["sets"][set_name]
    fold = {f.name: f for f in folds(specs, names, data_file, set_name)}[fold_name]
    overrides = ["learn.keep_remainder=false", *((wf.get("learn") or {}).get("residual") or []),
                 *[o for o in wf["generalization"]["residual"] if not o.startswith("learn.members")],
                 "learn.members=0"]
    flights = [f"results/ingest/{set_name}/{f}.parquet" for f in names]
    nis = [f"results/filter/{set_name}/{f}.nis.json" for f in names]
    est = [f"results/filter/{set_name}/{f}.crossfit.parquet" for f in names]
    train = list(held_out(flights, fold.split).train)
    pick = lambda files: [files[flights.index(f)] for f in train]  # noqa: E731
    settings = Settings.of(compose(overrides), fold.split)
    infos = check_flights(train, settings)
    vehicle_file = Path("results/generalization") / set_name / fold_name / "training_diagnosis" / "extended_vehicle.yaml"
    vehicle = load_vehicle(vehicle_file)
    rcfg, ecfg = settings.learn, settings.evaluate
    if "torque_remainder" in vehicle.raw:  # keep_remainder=false, as the fold's residual
        raw = vehicle.to_dict()
        raw.pop("torque_remainder")
        vehicle = vehicle_from_dict(raw, vehicle_file)
    cut = rollout_pieces(train, [read_flight(f) for f in train], vehicle, ecfg, settings.filter,
                         read_reports(pick(nis)), pick(est), log, vehicle_file)
    pieces = [(f, windows(st, meas, rcfg.horizon, ecfg.max_input_gap, keep)) for f, ps in zip(train, cut)
              for st, meas, keep in ps]
    _, val, by = holdout.validation(train, ecfg.split, rcfg.validation, infos)
    parts, split = rf.split(pieces, rcfg.horizon, rcfg.validation, rcfg.stride, val, by)
    return parts, split, settings, vehicle


def _launch_numba_pool() -> None:
    """Launch numba's OpenMP pool now (its first parallel call), so that the torch thread count
    :func:`qr.residual_fit.train` sets afterwards is the one that stays."""
    import numba
    import numpy as np

    @numba.njit(parallel=True)
    def total(x):
        s = 0.0
        for i in numba.prange(len(x)):
            s += x[i]
        return s

    total(np.ones(64))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("set", nargs="?", default="brushless")
    ap.add_argument("fold", nargs="?", default="speed-ts0.6-0.5")
    ap.add_argument("--batches", type=int, nargs="+", default=[64, 128, 256])
    ap.add_argument("--epochs", type=int, default=None, help="epoch limit (default: learn.epochs)")
    ap.add_argument("--only-scaled", action="store_true", help="larger batches with the scaled lr only")
    ap.add_argument("--threads", choices=("as-is", "one"), default="as-is",
                    help="one: numba's OpenMP pool launched before the first training (torch keeps one thread)")
    ap.add_argument("--again", action="store_true",
                    help="run the first setting once more at the end (same losses: a check of the seconds' drift)")
    a = ap.parse_args()
    if not Path("results/generalization", a.set, a.fold, "training_diagnosis", "extended_vehicle.yaml").exists():
        sys.exit(f"hybrid_batch.py: no results/generalization/{a.set}/{a.fold} here: run it from a folder whose "
                 "results/ holds the full workflow's tree")
    import torch

    from qr import residual_fit as rf

    if a.threads == "one":
        _launch_numba_pool()
    log = lambda m: print(m, file=sys.stderr, flush=True)  # noqa: E731
    t0 = time.perf_counter()
    parts, split, settings, vehicle = fold_parts(a.set, a.fold, log)
    base = settings.learn if a.epochs is None else replace(settings.learn, epochs=a.epochs)
    n_train = sum(len(p.train) for p in parts)
    print(f"fold {a.set} {a.fold}: {n_train} training windows ({len(split['training'])} flights), validation "
          f"flights {len(split['validation'])} (by {split['by']}); windows and estimates {time.perf_counter() - t0:.0f} s; "
          f"load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}", flush=True)
    b0 = a.batches[0]
    runs = []
    for b in a.batches:
        scales = [1.0] if b == b0 else ([math.sqrt(b / b0)] if a.only_scaled else [1.0, math.sqrt(b / b0)])
        runs += [(b, base.lr * s) for s in scales]
    if a.again:
        runs.append(runs[0])
    rows = []
    for b, lr in runs:
        cfg = replace(base, batch=b, lr=lr)
        log(f"-- learn.batch={b} learn.lr={lr:.4g}")
        c0 = time.process_time()
        clock = [c0]

        seen = []

        def on_epoch(e, clock=clock, seen=seen):
            now = time.process_time()
            seen.append(torch.get_num_threads())
            log(f"   epoch {e['epoch']}: {e['seconds']:.1f} s wall, {now - clock[0]:.1f} s CPU, torch threads "
                f"{seen[-1]}, validation loss {e['val_loss']!r}")
            clock[0] = now

        tr = rf.train(cfg, vehicle, parts, settings.seed, log, on_epoch=on_epoch)
        cpu = time.process_time() - c0
        secs = [e["seconds"] for e in tr.epochs]
        best = min([tr.initial["val_loss"]] + [e["val_loss"] for e in tr.epochs])
        rows.append((b, lr, len(tr.epochs), tr.best_epoch, best, sum(secs) / len(secs), min(secs), tr.wall_s,
                     cpu / len(tr.epochs), seen[0]))
        print(f"  done batch {b} lr {lr:.4g}: best validation loss {best:.4f} (epoch {tr.best_epoch}), "
              f"{sum(secs) / len(secs):.1f} s per epoch ({cpu / len(tr.epochs):.1f} s CPU); "
              f"load average {os.getloadavg()[0]:.1f}", flush=True)
    ref_loss, ref_epoch, ref_cpu = rows[0][4], rows[0][5], rows[0][8]
    print("\n| learn.batch | learn.lr | epochs run | best epoch | best validation loss | vs first | s per epoch "
          "(mean / min) | CPU s per epoch | vs first | training s | torch threads |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|")
    for b, lr, n, be, best, mean_s, min_s, wall, cpu_e, threads in rows:
        print(f"| {b} | {lr:.4g} | {n} | {be} | {best:.4f} | {best / ref_loss - 1:+.1%} | {mean_s:.1f} / {min_s:.1f} | "
              f"{cpu_e:.1f} | {cpu_e / ref_cpu:.2f} | {wall:.0f} | {threads} |")
    print(f"load average at the end {' '.join(f'{x:.1f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
