"""One ingest and one filter job per batch of flights vs one per flight: CPU and wall time.

    .venv/bin/python benchmarks/batch_jobs.py [--set payload] [--flights 8] [--repeat 2]

Ingests and filters the first N flights of a set of the Crazyflie data (QR_DATA, else
../shared/data/imrclab-crazyflie) twice: in N fresh processes per stage (as the workflow's per-flight
rules did) and in one process per stage (its batch rules, qr.stages.ingest_sets.ingest_batch and
qr.stages.filter_sets.run_batch), each process importing Snakemake's script preamble as a workflow job does.
Prints the user+system CPU time of the processes (little changed by other load on the machine) and their
wall time; the difference is the start-up a batch saves.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]


def _job(code: str) -> tuple[float, float]:
    """(CPU s, wall s) of a fresh Python running ``code``."""
    r0, t0 = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    subprocess.run([sys.executable, "-c", "import snakemake.script\n" + code], check=True, cwd=ROOT,
                   env={**os.environ, "QR_TRACKING": "off"}, stderr=subprocess.DEVNULL)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", default="payload")
    ap.add_argument("--flights", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    data = yaml.safe_load((ROOT / "conf" / "data" / "imrclab_crazyflie.yaml").read_text())
    root = Path(os.environ.get(data.get("root_env") or "", "") or ROOT / data["root"])
    s = data["sets"][args.set]
    flights = s["flights"][:args.flights]
    raw = [str(root / s.get("dir", "") / (f + s.get("suffix", ""))) for f in flights]
    vehicle = str(ROOT / "conf" / "vehicle" / f"{s['vehicle']}.yaml")
    with tempfile.TemporaryDirectory() as tmp:
        for rep in range(args.repeat):
            for mode in ("per flight", "batch"):
                out = Path(tmp) / mode.replace(" ", "_")
                shutil.rmtree(out, ignore_errors=True)
                out.mkdir()
                groups = [[f] for f in flights] if mode == "per flight" else [flights]
                times = {"ingest": [], "filter": []}
                for g in groups:
                    p = {k: [str(out / f"{f}{ext}") for f in g] for k, ext in
                         (("flight", ".parquet"), ("states", ".states.parquet"), ("nis", ".nis.json"),
                          ("crossfit", ".crossfit.parquet"))}
                    src = [raw[flights.index(f)] for f in g]
                    times["ingest"].append(_job(f"from qr.stages.ingest_sets import ingest_batch\n"
                                                f"ingest_batch({src!r}, {vehicle!r}, {p['flight']!r})"))
                    times["filter"].append(_job(f"from qr.stages.filter_sets import run_batch\n"
                                                f"run_batch({p['flight']!r}, {vehicle!r}, {p['states']!r}, "
                                                f"{p['nis']!r}, {p['crossfit']!r}, {g!r}, ['filter=auto'])"))
                line = "; ".join(f"{stage} CPU {sum(c for c, _ in t):.1f} s, wall {sum(w for _, w in t):.1f} s"
                                 for stage, t in times.items())
                print(f"{args.set}, {len(flights)} flights, {mode} ({len(groups)} job(s) per stage), run {rep + 1}: "
                      f"{line}", flush=True)


if __name__ == "__main__":
    main()
