"""The torch threads the workflow's rule ``learn_residual`` really trains on, and what one thread saves.

    .venv/bin/python benchmarks/residual_threads.py [SET] [--epochs N]

Run it from a folder whose ``results/`` holds the full workflow's tree (a link is enough); it writes only
to a temporary folder.  Makes the rule's call (workflow/scripts/learn_residual.py: :func:`qr.stages.
learn_residual_sets.train_held_out` with the filter stage's reports and cross-fit files,
``learn.keep_remainder=false``; here ``learn.members=0`` and ``--epochs`` epochs, default 1) twice, each in
a fresh interpreter (a cold process, as the rule's):

- ``as-is``: what the rule does.  Nothing launches numba's OpenMP pool before the training, so the
  training's first compiled rollout (numba ``parallel=True``) launches it inside, and that sets the
  OpenMP thread count torch shares back to numba's: torch trains on that many threads although
  :func:`qr.residual_fit.train` set one.
- ``pool-first``: ``numba.get_num_threads()`` (it launches the pool) is called before; torch keeps its one.

Prints per mode: torch's threads at each epoch's end (read in the log callback, inside the training), the
seconds per epoch and the validation losses (equal to the last digit in both modes).  Default set: brushed
(the smallest).  The machine may be shared: quote the figures with the load average printed.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = """
import sys, time
if sys.argv[1] == "pool-first":
    import numba
    numba.get_num_threads()
import torch, yaml
from qr.stages.learn_residual_sets import train_held_out
s, out, epochs = sys.argv[2], sys.argv[3], sys.argv[4]
names = yaml.safe_load(open(yaml.safe_load(open("conf/workflow.yaml"))["data"]))["sets"][s]["flights"]
seen = []
def log(m):
    if m.startswith("epoch"):
        seen.append(torch.get_num_threads())
train_held_out([f"results/ingest/{s}/{f}.parquet" for f in names],
               f"results/evaluation/{s}/training_diagnosis/extended_vehicle.yaml", out,
               ["learn.keep_remainder=false", f"learn.epochs={epochs}", "learn.members=0"],
               reports=[f"results/filter/{s}/{f}.nis.json" for f in names],
               estimates=[f"results/filter/{s}/{f}.crossfit.parquet" for f in names], track=False, log=log)
print(seen)
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("set", nargs="?", default="brushed")
    ap.add_argument("--epochs", type=int, default=1)
    a = ap.parse_args()
    if not Path("results/evaluation", a.set, "training_diagnosis", "extended_vehicle.yaml").exists():
        sys.exit(f"residual_threads.py: no results/evaluation/{a.set} here: run it from a folder whose results/ "
                 "holds the full workflow's tree")
    print(f"set {a.set}, {a.epochs} epoch(s); load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    print("| mode | torch threads per epoch | s per epoch | validation loss per epoch | process s |\n|---|---|---|---|---|")
    with tempfile.TemporaryDirectory(prefix="qr-residual-threads-") as d:
        for mode in ("as-is", "pool-first"):
            out = Path(d) / mode
            t0 = time.perf_counter()
            r = subprocess.run([sys.executable, "-c", CHILD, mode, a.set, str(out), str(a.epochs)],
                               capture_output=True, text=True)
            wall = time.perf_counter() - t0
            if r.returncode:
                sys.exit(r.stderr[-2000:])
            doc = json.loads((out / "training.json").read_text())
            ep = doc["loss_per_epoch"]
            secs = " / ".join(f"{e['seconds']:.1f}" for e in ep)
            losses = " / ".join(repr(e["val_loss"]) for e in ep)
            print(f"| {mode} | {r.stdout.strip().splitlines()[-1]} | {secs} | {losses} | {wall:.0f} |", flush=True)
    print(f"load average at the end {' '.join(f'{x:.1f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
