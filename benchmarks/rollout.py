"""Multi-step rollout on measured flights, held out by flight (issue 13's yardstick).

    .venv/bin/python benchmarks/rollout.py                       # brushless set (results/ingest/brushless)
    .venv/bin/python benchmarks/rollout.py --set payload --vehicle results/diagnosis/payload/vehicle.yaml

Every third flight (sorted by name) is held out; `qr diagnose` runs on the others (the workflow's
overrides for these short flights, its filter reports: the same function as rule `evaluate_held_out`,
so the same numbers as results/tables/rollout_held_out.md); `qr evaluate` then scores the nominal and the extended vehicle on
the held-out flights beside the references `hold` and `rate_frozen` (the public benchmark's
physics baseline).  Prints MAE at h = 1, 10, 50 per model and each model's ratio to `rate_frozen`
at h = 50.  Needs the workflow's ingest (`snakemake --cores 2 ingest_all` or a full run).

`--goals` prints issue 26's goal table from the workflow's own results (rules evaluate_held_out,
evaluate_learned, learn_residual: `snakemake --cores 2 results/tables/rollout_held_out.csv` first): the
held-out ratios to `rate_frozen` at h = 50 of `physical (refined)` (goal ≤ 1.0 / 1.0 / 1.0 / 1.5, every
written parameter in its physical range), the rollout-trained hybrid (≤ 0.6 / 0.6 / 0.7 / 0.6) and the
payload chain's hybrids (≤ 1.0 on all four), each set's training times (refinement, residual).

`--residual` also trains a residual through the rollout (`qr learn residual`, rule `learn_residual`'s
call) on the same training flights on top of the physical extended vehicle, rolls it out beside the
others ("rollout-trained") and prints its training wall time; `--residual-from DIR` flies a residual
trained elsewhere (DIR/hybrid_vehicle.yaml's network on this set's extended vehicle: the carried model),
and with `--residual` too, fine-tunes it on this set's training flights.
"""

import argparse
import glob
import json
import os
import tempfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("QR_TRACKING", "off")

from qr import rollout  # noqa: E402
from qr.holdout import held_out_by_flight  # noqa: E402
from qr.stages.evaluate_sets import evaluate_held_out  # noqa: E402

# conf/workflow.yaml: the measured diagnoses' overrides, and the held-out rule's learned torque remainder
WORKFLOW_OVERRIDES = ["diagnose.block_s=1.0", "diagnose.gap_s=0.5", "diagnose.horizon_s=0.5",
                      "diagnose.torque_remainder_ridge=0.001"]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--set", default="brushless")
    ap.add_argument("--vehicle", default="conf/vehicle/crazyflie21_brushless.yaml")
    ap.add_argument("--results", default="results")
    ap.add_argument("--extra", action="append", default=[], help="more diagnose overrides")
    ap.add_argument("--residual", action="store_true", help="train a residual through the rollout too")
    ap.add_argument("--residual-from", help="a qr learn residual output whose network to carry over")
    ap.add_argument("--learn", action="append", default=[], help="qr learn residual overrides")
    ap.add_argument("--goals", action="store_true", help="the goal table from the workflow's results")
    a = ap.parse_args()
    if a.goals:
        return goals(Path(a.results))
    flights = sorted(glob.glob(f"{a.results}/ingest/{a.set}/*.parquet"))
    if not flights:
        raise SystemExit(f"no flights in {a.results}/ingest/{a.set}: run the workflow's ingest first")
    train, test = held_out_by_flight(flights)
    nis = [f.replace("/ingest/", "/filter/").replace(".parquet", ".nis.json") for f in flights]
    tmp = Path(tempfile.mkdtemp(prefix="qr-rollout-"))
    print(f"{a.set}: diagnosing {len(train)} training flights, evaluating {len(test)} held-out flights")
    ev = evaluate_held_out(flights, nis, a.vehicle, tmp / "diag", tmp / "eval", WORKFLOW_OVERRIDES + a.extra)
    doc = json.loads((tmp / "diag" / "diagnosis.json").read_text())
    print("named:", ", ".join(e["name"] for e in doc["effects"]) or "nothing")
    names = {Path(a.vehicle).name: "nominal", "extended_physical.yaml": "extended", "extended_vehicle.yaml": "hybrid"}
    if a.residual or a.residual_from:
        ev = _with_residual(a, flights, nis, tmp)
        names.update({"hybrid_vehicle.yaml": "fine-tuned" if a.residual_from else "rollout-trained",
                      "carried_vehicle.yaml": "carried"})
    models = {names.get(k, k): v for k, v in ev["models"].items()}
    print(f"\nheld-out flights: {len(test)}, dt {ev['dt'] * 1e3:.1f} ms, H = {ev['horizon']}")
    print(f"{'model':16s}" + "".join(f"{q + '@' + str(h):>9s}" for q in rollout.QUANTITIES for h in (1, 10, 50)))
    for name, block in models.items():
        print(f"{name:16s}" + "".join(f"{rollout.at(block, h, q):9.4f}" for q in rollout.QUANTITIES for h in (1, 10, 50)))
    base = models["rate_frozen"]
    print("\nratio to rate_frozen at h = 50 (< 1: better than the benchmark's physics baseline)")
    for name, block in models.items():
        print(f"{name:16s}" + "".join(f"  {q} {rollout.at(block, 50, q) / rollout.at(base, 50, q):6.2f}"
                                      for q in rollout.QUANTITIES))
    print(f"\n(files in {tmp})")


def _with_residual(a, flights, nis, tmp):
    """Train (or carry) the rollout-trained residual and evaluate every model on the held-out flights again."""
    from qr.stages.evaluate import run_evaluation
    from qr.stages.learn_residual_sets import train_held_out
    from qr.vehicle import load_vehicle, save_vehicle

    _, test = held_out_by_flight(flights)
    reports = {f: json.loads(Path(p).read_text()) for f, p in zip(flights, nis)}
    ext = tmp / "diag" / "extended_vehicle.yaml"
    models = [a.vehicle, str(ext)]
    if load_vehicle(ext).raw.get("torque_remainder"):
        physical = load_vehicle(ext).to_dict()
        physical.pop("torque_remainder")
        save_vehicle(physical, tmp / "extended_physical.yaml")
        models.insert(1, str(tmp / "extended_physical.yaml"))
    if a.residual_from:
        raw = load_vehicle(tmp / "extended_physical.yaml" if len(models) == 3 else ext).to_dict()
        raw["residual"] = load_vehicle(Path(a.residual_from) / "hybrid_vehicle.yaml").raw["residual"]
        save_vehicle(raw, tmp / "carried_vehicle.yaml")
        models.append(str(tmp / "carried_vehicle.yaml"))
    if a.residual:
        base = tmp / "carried_vehicle.yaml" if a.residual_from else ext  # the carried network: fine-tuned
        doc = train_held_out(flights, base, tmp / "residual", ["learn.keep_remainder=false", *a.learn], reports=nis,
                             track=False, log=lambda m: print(m) if m.startswith("epoch") else None)
        print(f"rollout-trained residual: {doc['wall_s']['training']:.0f} s of training "
              f"({doc['epochs']['run']} epochs, best {doc['epochs']['best']}) after {doc['wall_s']['estimates']:.0f} s "
              f"of estimates; {doc['windows']['training']} training windows")
        models.append(str(tmp / "residual" / "hybrid_vehicle.yaml"))
    return run_evaluation(test, models, tmp / "eval_residual", log=lambda m: None, reports=[reports[f] for f in test])


SHOWN = ("physical (refined)", "hybrid (rollout-trained)", "hybrid (rollout-trained, carried over)",
         "hybrid (rollout-trained, fine-tuned)")
GOALS = {("brushless", "physical (refined)"): (1.0, 1.0, 1.0, 1.5),  # issue 26 (the other sets: no goal)
         ("brushless", "hybrid (rollout-trained)"): (0.6, 0.6, 0.7, 0.6),
         ("payload", "hybrid (rollout-trained, carried over)"): (1.0,) * 4,
         ("payload", "hybrid (rollout-trained, fine-tuned)"): (1.0,) * 4}


def goals(results: Path):
    """Issue 26's goals against the workflow's held-out evaluations (every set it ran)."""
    rows = []
    for d in sorted((results / "evaluation").glob("*/held_out/evaluation.json")):
        s = d.parent.parent.name
        docs = [json.loads(d.read_text())]
        learned = d.parent.parent / "learned" / "evaluation.json"
        if learned.exists():
            docs.append(json.loads(learned.read_text()))
        diag = json.loads((d.parent.parent / "training_diagnosis" / "diagnosis.json").read_text())
        ref = diag.get("refine") or {}
        train = results / "learn" / "residual" / s / "training.json"
        t_res = json.loads(train.read_text())["wall_s"]["training"] if train.exists() else None
        print(f"{s}: {len(docs[0]['flights'])} held-out flights; refinement {ref.get('wall_s', float('nan')):.0f} s "
              f"({ref.get('windows', 0)} windows), residual training "
              + (f"{t_res:.0f} s" if t_res is not None else "–"))
        for doc in docs:
            H, m = doc["horizon"], doc["models"]
            for k, label in doc["labels"].items():
                if label not in SHOWN or k not in m:
                    continue
                r = [rollout.at(m[k], H, q) / rollout.at(m["rate_frozen"], H, q) for q in rollout.QUANTITIES]
                g = GOALS.get((s, label))
                out = [p["label"] for p in ref.get("parameters", []) if label == "physical (refined)"
                       and not p["physical_range"][0] <= p["written"] <= p["physical_range"][1]]
                met = g is not None and all(x <= y for x, y in zip(r, g)) and not out
                rows.append((s, label, r, g, met))
                print(f"  {label:40s}" + " / ".join(f"{x:.2f}" for x in r)
                      + ("   (no goal)" if g is None else "   goal ≤ " + " / ".join(f"{x:g}" for x in g)
                         + ("   met" if met else "   not met"))
                      + (f"; out of its physical range: {', '.join(out)}" if out else ""))
    if not rows:
        raise SystemExit(f"no held-out evaluations in {results}/evaluation: run the workflow first")


if __name__ == "__main__":
    main()
