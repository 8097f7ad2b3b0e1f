"""Where one held-out fold's time goes (rule ``generalization_fold``, :func:`qr.stages.evaluate_sets.run_fold`;
issue 35).

    .venv/bin/python benchmarks/fold_profile.py                      # the reduced workflow's fold (conf/workflow_ci.yaml)
    .venv/bin/python benchmarks/fold_profile.py --configfile none --fold brushed/trajectory-figure8 \\
        --results /path/to/a/full/run/results                        # a fold of the full workflow
    .venv/bin/python benchmarks/fold_profile.py --out /tmp/fold --keep --top 40

The fold's parameters (its split, the diagnosis and residual overrides, the vehicle, the flights) are the
workflow's own: the Snakefile is parsed (``snakemake --list-rules`` on a wrapper that includes it) with the
given ``--configfile`` and the rule's parameter functions are called.  The fold's inputs are the workflow's
ingest and filter outputs (``--results``: a results folder of an earlier run, read only; the payload set's
vehicle is its ``diagnosis/payload/vehicle.yaml``).  The fold runs once in this process under cProfile (MLflow
tracking on, into a store under ``--out``) and prints the time of each part: reading, convention checks,
segments, estimates, the diagnosis and its refinement, the residual's main network and ensemble, the
evaluation rollouts, figures, MLflow; then, with ``--top``, the functions with the most cumulative time.
Each part is the time spent in calls entering it from outside it (so a part called from several steps
counts every call).  Under cProfile the figures are inflated a little (Python-heavy parts the most).
"""

import argparse
import cProfile
import json
import os
import pstats
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]

WRAPPER = """include: {snakefile!r}
import json as _json
_out = {{}}
for _s, _fs in GEN_FOLDS.items():
    for _f, _fold in _fs.items():
        _kw = dict(extra=EVAL.get("experiments", []), extra_overrides=EVAL.get("overrides", []))
        _out[f"{{_s}}/{{_f}}"] = {{
            "fold": _fold.to_dict(), "overrides": diagnosis_overrides(_s, **_kw),
            "single": diagnosis_overrides(_s, each=True, **_kw),
            "residual": ["learn.keep_remainder=false", *LEARN.get("residual", []), *GEN.get("residual", [])],
            "vehicle": diagnosis_vehicle(type("W", (), {{"set": _s}})()),
            "flights": flights_of(_s, INGESTED), "nis": flights_of(_s, FILTERED["nis"]),
            "crossfit": flights_of(_s, FILTERED["crossfit"])}}
print("FOLDS=" + _json.dumps(_out))
"""

# part -> what it is: (file suffix, function names (None: every function of the file)[, the callers' file])
PARTS = {
    "reading flights (parquet)": [("qr/flight.py", {"read_flight"})],
    "filter reports (.nis.json)": [("qr/intake.py", {"read_reports"})],
    "convention checks": [("qr/intake.py", {"check_conventions"})],
    "segments (cutting)": [("qr/segments.py", {"flight_segments"})],
    "estimates (cross-fit file / filters)": [("qr/intake.py", {"_estimates"})],
    "diagnosis: refinement (refine=rollout)": [("qr/diagnose/refine.py", {"refine_diagnosis"})],
    "residual: main network": [("qr/residual_fit.py", {"train"}, "qr/residual_training/training.py")],
    "residual: ensemble members": [("qr/ensemble.py", {"train_members"})],
    "residual: ensemble calibration": [("qr/ensemble.py", {"calibrated"})],
    "residual: validation blocks": [("qr/residual_fit.py", {"validation_blocks"})],
    "evaluation rollouts (qr.evaluate run)": [("qr/evaluate/evaluation.py", {"run"})],
    "figures and reports": [("qr/diagnose/report.py", {"make_figures", "write_report"}),
                            ("qr/diagnose/drawing.py", None), ("qr/evaluate/report.py", {"write"}),
                            ("qr/residual_training/report.py", {"curve_figure", "report"})],
    "MLflow": [("qr/tracking.py", None)],
}
# the diagnosis's identification: its run minus the parts above that it calls
DIAGNOSIS = [("qr/diagnose/diagnosis.py", {"run"})]


def fold_params(configfile: str | None) -> dict:
    """Fold name -> the rule's parameters, from the workflow itself."""
    with tempfile.TemporaryDirectory() as d:
        wrapper = Path(d) / "folds.smk"
        wrapper.write_text(WRAPPER.format(snakefile=str(ROOT / "Snakefile")))
        cmd = [str(Path(sys.executable).parent / "snakemake"), "-s", str(wrapper), "-d", str(ROOT), "--list-rules"]
        if configfile:
            cmd += ["--configfile", configfile]
        out = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    line = next((ln for ln in out.stdout.splitlines() if ln.startswith("FOLDS=")), None)
    if line is None:
        sys.exit(f"could not read the workflow's folds:\n{out.stderr[-2000:]}")
    return json.loads(line[len("FOLDS="):])


def _matches(func, specs) -> bool:
    file, _, name = func
    return any(file.endswith(s[0]) and (s[1] is None or name in s[1]) for s in specs)


def entered(stats: dict, specs) -> float:
    """Seconds in calls into the functions ``specs`` names from outside them (cumulative; where a spec names
    the callers' file, from there only)."""
    total = 0.0
    for func, (_, _, _, _, callers) in stats.items():
        for s in specs:
            if _matches(func, [s]):
                total += sum(c[3] for caller, c in callers.items() if not _matches(caller, specs)
                             and (len(s) < 3 or caller[0].endswith(s[2])))
    return total


def breakdown(stats: dict, wall: float) -> list[tuple[str, float]]:
    rows = [(name, entered(stats, specs)) for name, specs in PARTS.items()]
    # the identification: the diagnosis's run minus its refinement (called inside it only)
    ident = entered(stats, DIAGNOSIS) - entered(stats, PARTS["diagnosis: refinement (refine=rollout)"])
    rows.insert(5, ("diagnosis: identification (its run, without the refinement)", ident))
    rows.append(("other (imports, Hydra, writing, rest)", wall - sum(t for _, t in rows)))
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--configfile", default="conf/workflow_ci.yaml",
                    help="the workflow's --configfile (none: conf/workflow.yaml alone, the full workflow)")
    ap.add_argument("--fold", help="SET/FOLD (default: the configuration's first fold)")
    ap.add_argument("--results", default="results", help="the results folder holding the fold's inputs")
    ap.add_argument("--out", help="the fold's output folder (default: a temporary folder)")
    ap.add_argument("--top", type=int, default=0, help="also print the N functions with the most cumulative time")
    ap.add_argument("--no-profile", action="store_true", help="timers only (the fold's own fold.json seconds)")
    ap.add_argument("--stats", help="save the cProfile stats here")
    ap.add_argument("--cpu", action="store_true", help="this process's CPU time instead of wall time (steadier on a "
                    "loaded machine; the ensemble's member processes are not in it)")
    a = ap.parse_args()
    folds = fold_params(None if a.configfile == "none" else a.configfile)
    name = a.fold or next(iter(folds))
    if name not in folds:
        sys.exit(f"no fold {name}; the configuration's folds: {', '.join(folds)}")
    p = folds[name]
    res = Path(a.results).resolve()
    where = lambda f: str(res / Path(f).relative_to("results")) if f.startswith("results/") else f  # noqa: E731
    out = Path(a.out or tempfile.mkdtemp(prefix="qr-fold-profile-")).resolve()
    out.mkdir(parents=True, exist_ok=True)
    # MLflow's store, never the workflow's (QR_RESULTS: one made by an earlier run, without its creation's cost)
    os.environ.setdefault("QR_RESULTS", str(out / "store"))
    os.chdir(ROOT)  # the fold's data file (conf/data/...) is named relative to the repository
    clock = time.process_time if a.cpu else time.perf_counter
    t0 = clock()
    from qr.holdout import Fold
    from qr.stages.evaluate_sets import run_fold

    args = ([where(f) for f in p["flights"]], [where(f) for f in p["nis"]], where(p["vehicle"]), out / "fold",
            Fold.from_dict(p["fold"]), p["overrides"], p["single"], p["residual"])
    kw = dict(estimates=[where(f) for f in p["crossfit"]], track=f"fold:{name}")
    print(f"fold {name}: {len(p['flights'])} flights, overrides {p['overrides']}, residual {p['residual']}",
          flush=True)
    prof = None if a.no_profile else cProfile.Profile(clock)
    if prof:
        prof.enable()
    doc = run_fold(*args, **kw)
    if prof:
        prof.disable()
    wall = clock() - t0
    print(f"\n{'CPU' if a.cpu else 'wall'} {wall:.1f} s (imports included); the fold's own steps (fold.json, wall s): "
          + ", ".join(f"{k} {v:.1f}" for k, v in doc["seconds"].items()))
    if prof:
        stats = pstats.Stats(prof).stats
        print(f"\n{'part':55s} {'s':>8s} {'%':>6s}")
        for part, t in breakdown(stats, wall):
            print(f"{part:55s} {t:8.1f} {100 * t / wall:6.1f}")
        n_read = sum(v[1] for f, v in stats.items() if _matches(f, PARTS["reading flights (parquet)"]))
        n_checked = sum(v[1] for f, v in stats.items() if _matches(f, PARTS["convention checks"]))
        print(f"\nflights read {n_read} times, convention-checked {n_checked} times "
              f"({len(p['flights'])} flights in the set)")
        if a.stats:
            prof.dump_stats(a.stats)
        if a.top:
            pstats.Stats(prof).sort_stats("cumulative").print_stats(a.top)
    print(f"outputs: {out / 'fold'}")


if __name__ == "__main__":
    main()
