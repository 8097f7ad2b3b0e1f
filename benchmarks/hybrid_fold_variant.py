"""A variant of a generalisation fold's rollout-trained hybrid, trained and scored beside the fold's own.

    .venv/bin/python benchmarks/hybrid_fold_variant.py SET FOLD OUT [HYDRA_OVERRIDES...]

Reuses the fold of rule generalization_fold (`results/generalization/SET/FOLD`: its training diagnosis's
vehicle) and trains `qr learn residual` on the fold's training flights with the workflow's residual
overrides plus the given ones (into OUT/residual), then scores it on the fold's held-out flights as the
workflow does (OUT/learned).  Prints the validation ratios (the training side's own flights: what a default
may be chosen on) and then the held-out ratios (to report only), p / v / R / ω at h = H.  Run the fold first.
"""

import json
import sys
import time
from pathlib import Path

import yaml

from qr.holdout import folds
from qr.stages.evaluate_sets import RESIDUAL_LABEL, evaluate_learned
from qr.stages.learn_residual_sets import train_held_out

set_name, fold_name, out = sys.argv[1], sys.argv[2], Path(sys.argv[3])
extra = sys.argv[4:]
wf = yaml.safe_load(Path("conf/workflow.yaml").read_text())
data_file = wf["data"]
data = yaml.safe_load(Path(data_file).read_text())
names = data["sets"][set_name]["flights"]
specs = (data.get("workflow") or {}).get("generalization", {}).get("sets", {})[set_name]
fold = {f.name: f for f in folds(specs, names, data_file, set_name)}[fold_name]
res = ["learn.keep_remainder=false", *((wf.get("learn") or {}).get("residual") or []),
       *[o for o in wf["generalization"]["residual"] if not o.startswith("learn.members")], "learn.members=0", *extra]
flights = [f"results/ingest/{set_name}/{f}.parquet" for f in names]
nis = [f"results/filter/{set_name}/{f}.nis.json" for f in names]
est = [f"results/filter/{set_name}/{f}.crossfit.parquet" for f in names]
src = Path("results/generalization") / set_name / fold_name
out.mkdir(parents=True, exist_ok=True)
t0 = time.perf_counter()
doc = train_held_out(flights, src / "training_diagnosis" / "extended_vehicle.yaml", out / "residual", res,
                     reports=nis, estimates=est, split=fold.split, track=False, force=True,
                     log=lambda m: print(m, file=sys.stderr, flush=True))
t1 = time.perf_counter()
evaluate_learned(flights, nis, src / "training_diagnosis" / "extended_vehicle.yaml",
                 [out / "residual" / "hybrid_vehicle.yaml"], [RESIDUAL_LABEL], out / "learned",
                 estimates=est, split=fold.split)
ep = doc["epochs"]
best = min([doc["initial_loss"]["val_loss"]] + [e["val_loss"] for e in doc["loss_per_epoch"]])
print(f"overrides {' '.join(extra) or '(defaults)'}; residual {t1 - t0:.0f} s (under load), epochs run {ep['run']}, "
      f"best {ep['best']} ({ep['stopped']}); best validation loss {best:.4f} (start {doc['initial_loss']['val_loss']:.4f})")
r = doc["validation"]["ratio_to_rate_frozen_at_H"]
fmt = lambda d: " / ".join(f"{d[q]:.2f}" for q in ("p", "v", "R", "w"))  # noqa: E731
print(f"validation flights {doc['flights']['validation']}: vehicle {fmt(r['vehicle'])}; hybrid {fmt(r['hybrid'])}")
ev = json.loads((out / "learned" / "evaluation.json").read_text())
H = ev["horizon"]


def at(block, q):
    from qr.rollout import at as at_h
    return at_h(block, H, q)


m = ev["models"]
names = dict(zip(m, ["hold", "rate_frozen", "nominal", "hybrid"])) if len(m) == 4 else {k: k for k in m}
print(f"held out ({(ev.get('envelope') or {}).get('share_outside', float('nan')):.0%} of windows outside the envelope): "
      + "; ".join(f"{names[k]} " + " / ".join(f"{at(m[k], q) / at(m['rate_frozen'], q):.2f}" for q in ("p", "v", "R", "w"))
                  for k in m if k not in ("hold", "rate_frozen")))
