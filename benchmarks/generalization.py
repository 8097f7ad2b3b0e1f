"""The generalisation table of the last workflow run, and what its folds cost.

    .venv/bin/python benchmarks/generalization.py [results]

Prints results/tables/generalization.md (rule generalization_summary: per set and split, each model's MAE at
h = 50 over rate_frozen's on flights it was not trained on; the repeat split, every third flight, measures
interpolation), then one line per fold of rule generalization_fold: what it held out, how many flights it
trained on and scored, the share of scored windows outside the training envelope, and the seconds of its
steps (the training diagnosis with the refinement and the rollout; the residual trained through the
rollout; its rollout) and of the whole job (Snakemake's benchmark file).  Run the workflow first
(`snakemake --cores 2 results/tables/generalization.csv`).
"""

import json
import sys
from pathlib import Path

import pandas as pd

root = Path(sys.argv[1] if len(sys.argv) > 1 else "results")
md = root / "tables" / "generalization.md"
if not md.exists():
    raise SystemExit(f"no {md}: run the workflow first (snakemake --cores 2 results/tables/generalization.csv)")
print(md.read_text())
rows = []
for f in sorted((root / "generalization").glob("*/*/fold.json")):
    d = json.loads(f.read_text())
    set_name, fold = f.parent.parent.name, f.parent.name
    ev = json.loads((f.parent / "held_out" / "evaluation.json").read_text())
    bench = root / "benchmarks" / "evaluate" / f"generalization_{set_name}_{fold}.tsv"
    job = float(pd.read_csv(bench, sep="\t")["s"].iloc[-1]) if bench.exists() else float("nan")
    sec = d["seconds"]
    rows.append({"set": set_name, "fold": fold, "held out": d["split"]["held_out"], "trained": len(d["split"]["train"]),
                 "scored": len(d["split"]["test"]),
                 "outside envelope": (ev.get("envelope") or {}).get("share_outside"),
                 "diagnose + evaluate s": sec.get("diagnose_and_evaluate"), "residual s": sec.get("residual"),
                 "residual rollout s": sec.get("evaluate_residual"), "job s": job})
if rows:
    t = pd.DataFrame(rows)
    print(t.to_markdown(index=False, floatfmt=".3g"))
    print(f"\nsum of the folds' job times: {t['job s'].sum():.0f} s (2 cores run two jobs at a time)")
