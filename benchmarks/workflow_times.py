"""Where the time of the last workflow run went, per rule, from Snakemake's `benchmark:` files.

    .venv/bin/python benchmarks/workflow_times.py [RESULTS/benchmarks] [--no-startup] [--repeat N] [--rules DIR]

Prints a Markdown table, one row per rule (the batch rules ingest_<set>_<k> and filter_<set>_<k>
as one row each): jobs, job time (sum, mean, longest, s), peak memory (MB), and the start-up share:
jobs x the cold start-up of the rule's script (a fresh Python importing Snakemake's script preamble and
the script's top-level imports, measured here: the median of ``--repeat`` runs) over the rule's job
time.  Imports inside functions and the loading of numba's compiled kernels count as work, so the
share is a lower bound.  Each rule is found by matching its `benchmark:` pattern in workflow/rules/*.smk
(``--rules``: another checkout's, for a run made by another version of the workflow).
"""

from __future__ import annotations

import argparse
import ast
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
BLOCK = re.compile(r"^\s*rule\s*(\w*)\s*:\s*$")


def rule_patterns(rules: Path) -> list[tuple[str, re.Pattern, str]]:
    """(rule, regex of its benchmark path under results/benchmarks/, script path) of every rule with a
    benchmark, the most specific pattern first (``evaluate/summary.tsv`` before ``evaluate/{set}.tsv``)."""
    out = []
    for smk in sorted(rules.glob("*.smk")):
        lines = smk.read_text().splitlines()
        starts = [i for i, line in enumerate(lines) if BLOCK.match(line)]
        for i, start in enumerate(starts):
            body = "\n".join(lines[start:starts[i + 1] if i + 1 < len(starts) else len(lines)])
            name = BLOCK.match(lines[start]).group(1)
            if not name:  # a rule defined in a loop: `name: batch_rule("ingest", _set, _k)`
                m = re.search(r'batch_rule\("(\w+)"', body)
                name = f"{m.group(1)}_<set>_<k>" if m else "?"
            bench = re.search(r'benchmark:\s*\n\s*f?"([^"]+)"', body)
            script = re.search(r'script:\s*\n\s*"([^"]+)"', body)
            if bench:
                rel = bench.group(1).removeprefix("results/benchmarks/")
                literal = re.sub(r"\{[^}]*\}", "", rel)
                regex = re.sub(r"\\\{[^}]*\\\}", "[^/]+", re.escape(rel))  # {set}, {_k}: within one folder name
                spec = (rel.count("{"), -len(literal))
                out.append((spec, name, re.compile(regex + "$"), str((rules / script.group(1)).resolve()) if script else ""))
    return [x[1:] for x in sorted(out, key=lambda x: x[0])]


def startup_s(script: str, repeat: int) -> float:
    """The cold start-up of a workflow script: Python, Snakemake's script preamble, the script's top-level
    imports (median of ``repeat`` fresh processes)."""
    path = Path(script)
    imports = [ast.unparse(n) for n in ast.parse(path.read_text()).body if isinstance(n, (ast.Import, ast.ImportFrom))]
    code = "\n".join(["import snakemake.script", *imports])
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT, capture_output=True)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("benchmarks", nargs="?", default="results/benchmarks")
    ap.add_argument("--no-startup", action="store_true", help="do not measure the scripts' start-up")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--rules", default=str(ROOT / "workflow" / "rules"), help="the workflow's rule files")
    args = ap.parse_args()
    root = Path(args.benchmarks)
    patterns = rule_patterns(Path(args.rules))
    rows = []
    for f in sorted(root.rglob("*.tsv")):
        rel = str(f.relative_to(root))
        rule, script = next(((r, s) for r, rx, s in patterns if rx.match(rel)), (f"? {rel}", ""))
        b = pd.read_csv(f, sep="\t")
        rows.append({"rule": rule, "script": script, "s": float(b["s"].iloc[-1]),
                     "max_rss": pd.to_numeric(b["max_rss"], errors="coerce").iloc[-1]})
    if not rows:
        sys.exit(f"no benchmark files under {root}: run the workflow first")
    t = (pd.DataFrame(rows).groupby(["rule", "script"])
         .agg(jobs=("s", "size"), job_s=("s", "sum"), mean_s=("s", "mean"), longest_s=("s", "max"),
              peak_mb=("max_rss", "max"))
         .reset_index().sort_values("job_s", ascending=False))
    if not args.no_startup:
        cold = {s: startup_s(s, args.repeat) for s in t["script"].unique() if s}
        t["startup_s"] = t["script"].map(cold) * t["jobs"]
        t["startup_share"] = t["startup_s"] / t["job_s"]
    print(t.drop(columns="script").to_markdown(index=False, floatfmt=".2f"))
    total = t["job_s"].sum()
    print(f"\n{int(t['jobs'].sum())} jobs, {total:.0f} s of job time (2 cores run two jobs at a time)", end="")
    if not args.no_startup:
        print(f"; start-up {t['startup_s'].sum():.0f} s of it ({t['startup_s'].sum() / total:.0%}, a lower bound: "
              "imports inside functions count as work)")
    else:
        print()


if __name__ == "__main__":
    main()
