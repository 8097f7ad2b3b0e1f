"""The refined physical model on flights of other trajectories than its training ones (issue 33, part 2).

    .venv/bin/python benchmarks/refine_holdout.py                       # brushless: time scales 1.0-0.7 train, 0.6-0.5 scored
    .venv/bin/python benchmarks/refine_holdout.py --train eckart00 eckart01 --score eckart22 eckart27
    .venv/bin/python benchmarks/refine_holdout.py --extra diagnose.refine_rotors=false

The training and scored flights are inputs (``--train``, ``--score``: names in ``results/ingest/SET``), so any
split can be measured; the default is the brushless set's speed hold-out, the figure-8 trained at
TIMESCALE 1.0, 0.9, 0.8, 0.7 and scored at 0.6 and 0.5 (``../shared/data/imrclab-crazyflie/SOURCE.md``:
flights per time scale).  ``qr diagnose … diagnose.refine=rollout`` runs on the training flights with the
workflow's overrides for these short flights and their filter reports (as rule ``evaluate_held_out``), then
``qr evaluate`` scores the nominal, the one-step (``extended``) and the refined (``physical (refined)``)
vehicle on the scored flights beside ``rate_frozen``.  Prints each model's ratio to ``rate_frozen`` at h = 50
(p / v / R / ω), the refinement's wall time and what it wrote.  Needs the workflow's ingest and filter
outputs for the flights (``snakemake --cores 2 results/filter/SET/FLIGHT.nis.json …``).
"""

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("QR_TRACKING", "off")

from qr import rollout  # noqa: E402

# SOURCE.md: "0,1,2,3,4: 1.0 / 6,7,8,9,11: 0.9 / 12..16: 0.8 / 17..21: 0.7 / 22..26: 0.6 / 27, 30, 34, 35, 36: 0.5"
SCALES = {1.0: "00 01 02 03 04", 0.9: "06 07 08 09 11", 0.8: "12 13 14 15 16", 0.7: "17 18 19 20 21",
          0.6: "22 23 24 25 26", 0.5: "27 30 34 35 36"}
TRAIN = [f"eckart{n}" for s in (1.0, 0.9, 0.8, 0.7) for n in SCALES[s].split()]
SCORED = [f"eckart{n}" for s in (0.6, 0.5) for n in SCALES[s].split()]
OVERRIDES = ["+experiment=[crazyflie_short_flights,refine]"]


def main():
    from qr.stages.diagnose import run_diagnosis
    from qr.stages.evaluate import run_evaluation
    from qr.stages.evaluate_sets import held_out_models

    ap = argparse.ArgumentParser()
    ap.add_argument("--set", default="brushless")
    ap.add_argument("--vehicle", default="conf/vehicle/crazyflie21_brushless.yaml")
    ap.add_argument("--results", default="results")
    ap.add_argument("--train", nargs="+", default=TRAIN)
    ap.add_argument("--score", nargs="+", default=SCORED)
    ap.add_argument("--extra", action="append", default=[], help="more diagnose overrides")
    ap.add_argument("--keep", help="write the diagnosis and evaluation here (default: a temporary folder)")
    a = ap.parse_args()
    res = Path(a.results)
    flight = lambda n: str(res / "ingest" / a.set / f"{n}.parquet")  # noqa: E731
    nis = lambda n: json.loads((res / "filter" / a.set / f"{n}.nis.json").read_text())  # noqa: E731
    est = lambda n: str(res / "filter" / a.set / f"{n}.crossfit.parquet")  # noqa: E731
    out = Path(a.keep or tempfile.mkdtemp(prefix="qr-refine-holdout-"))
    out.mkdir(parents=True, exist_ok=True)  # qr writes into an existing folder only
    print(f"{a.set}: training on {len(a.train)} flights, scoring {len(a.score)}", flush=True)
    t0 = time.perf_counter()
    doc, diagnosis = run_diagnosis([flight(n) for n in a.train], a.vehicle, out / "diag", OVERRIDES + a.extra,
                                   track=False, figures=False, reports=[nis(n) for n in a.train],
                                   estimates=[est(n) for n in a.train], log=lambda m: None, return_result=True)
    wall = time.perf_counter() - t0
    files, models, labels = held_out_models(a.vehicle, diagnosis, doc, out / "models")
    ev = run_evaluation([flight(n) for n in a.score], files, out / "eval", figures=False,
                        reports=[nis(n) for n in a.score], estimates=[est(n) for n in a.score], labels=labels,
                        log=lambda m: None, loaded=models)
    m, H = ev["models"], ev["horizon"]
    print(f"\nratio to rate_frozen at h = {H} on the scored flights (p / v / R / w):")
    for key, block in m.items():
        label = ev["labels"].get(key, key)
        print(f"  {label:22s}" + " ".join(f"{rollout.at(block, H, q) / rollout.at(m['rate_frozen'], H, q):6.3f}"
                                          for q in rollout.QUANTITIES))
    ref = doc.get("refine") or {}
    print(f"\ndiagnosis with the refinement: {wall:.0f} s (refinement {ref.get('wall_s', float('nan')):.0f} s, "
          f"{ref.get('windows', 0)} windows); named: {', '.join(e['name'] for e in doc['effects']) or 'nothing'}")
    for p in ref.get("parameters", []):
        if p.get("refined", True) and p["written"] != p["one_step"]:
            print(f"  written {p['label']}: {p['one_step']:.4g} -> {p['written']:.4g}")
    for k, v in (ref.get("vehicle_keys") or {}).items():
        print(f"  vehicle key {k}: {v}")
    print(f"(files in {out})")


if __name__ == "__main__":
    main()
