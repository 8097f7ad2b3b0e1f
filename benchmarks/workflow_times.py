"""Per-rule wall-clock times of the last workflow run, from Snakemake's `benchmark:` files.

    .venv/bin/python benchmarks/workflow_times.py [results/benchmarks]

Prints a Markdown table: rule, jobs, total and longest job time (s), peak memory (MB).
"""

import sys
from pathlib import Path

import pandas as pd

root = Path(sys.argv[1] if len(sys.argv) > 1 else "results/benchmarks")
rows = []
for f in sorted(root.rglob("*.tsv")):
    b = pd.read_csv(f, sep="\t")
    rel = f.relative_to(root)
    stage = rel.parts[0]
    # per-flight jobs live in <stage>/<set>/<flight>.tsv; one-off jobs in <stage>/<name>.tsv
    rule = f"{stage} (per flight)" if len(rel.parts) == 3 and stage in ("ingest", "filter") else f"{stage}/{rel.stem}"
    rows.append({"rule": rule, "s": float(b["s"].iloc[-1]), "max_rss": float(b["max_rss"].iloc[-1])})
t = pd.DataFrame(rows).groupby("rule").agg(jobs=("s", "size"), total_s=("s", "sum"), longest_s=("s", "max"),
                                            peak_mb=("max_rss", "max")).reset_index()
print(t.to_markdown(index=False, floatfmt=".1f"))
print(f"\nsum of job times: {t['total_s'].sum():.0f} s (2 cores run two jobs at a time)")
