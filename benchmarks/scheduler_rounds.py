"""Snakemake's own scheduling rounds and CPU, as it ships and with workflow/rules/scheduler.smk.

    .venv/bin/python benchmarks/scheduler_rounds.py                 # 60 jobs of 1 s
    .venv/bin/python benchmarks/scheduler_rounds.py --jobs 120 --seconds 2

A workflow of ``--jobs`` independent jobs that each sleep ``--seconds`` (no CPU of their own) is run with
``snakemake --cores 2 --verbose`` in a temporary folder twice: as Snakemake ships, and with qr's
``scheduler.smk`` included first (one pending re-evaluation of the scheduler at a time).  Per run: the wall
time, the CPU seconds of the snakemake process and what it waited for (the sleeping jobs add next to
nothing), and the scheduling rounds (Snakemake's debug line "Resources before job selection").  As shipped,
every finished job starts one more chain of 1 s re-evaluations, so the rounds grow with the square of the jobs.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = str(Path(sys.executable).with_name("snakemake"))


def snakefile(jobs: int, seconds: float, patched: bool) -> str:
    head = f'include: "{ROOT / "workflow" / "rules" / "scheduler.smk"}"\n\n' if patched else ""
    return head + f"""
rule all:
    input: expand("out/{{i}}.txt", i=range({jobs}))

rule one:
    output: "out/{{i}}.txt"
    shell: "sleep {seconds} && touch {{output}}"
"""


def run(jobs: int, seconds: float, patched: bool) -> dict:
    with tempfile.TemporaryDirectory() as d:
        Path(d, "Snakefile").write_text(snakefile(jobs, seconds, patched))
        log = Path(d, "log.txt")
        t0 = time.perf_counter()
        with open(log, "w") as out:
            p = subprocess.Popen([SNAKEMAKE, "--cores", "2", "--verbose", "--nolock"], cwd=d, stdout=out,
                                 stderr=subprocess.STDOUT)
            _, status, ru = os.wait4(p.pid, 0)
        wall = time.perf_counter() - t0
        rounds = log.read_text(errors="replace").count("Resources before job selection")
        return {"wall_s": wall, "cpu_s": ru.ru_utime + ru.ru_stime, "rounds": rounds,
                "rc": os.waitstatus_to_exitcode(status)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=60)
    ap.add_argument("--seconds", type=float, default=1.0)
    a = ap.parse_args()
    print(f"{a.jobs} jobs of {a.seconds:g} s on 2 cores; load average {os.getloadavg()[0]:.1f}")
    print("| scheduler | wall (s) | snakemake CPU (s) | scheduling rounds |")
    print("|---|---:|---:|---:|")
    for patched in (False, True):
        r = run(a.jobs, a.seconds, patched)
        assert r["rc"] == 0, r
        name = "with workflow/rules/scheduler.smk" if patched else "as shipped"
        print(f"| {name} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | {r['rounds']} |", flush=True)


if __name__ == "__main__":
    main()
