"""Cold start of the `qr` commands: `qr <stage> --help` in a fresh process, as a user (and
tests/core/test_cli_help.py, ~30 such processes) starts it.

    .venv/bin/python benchmarks/cold_start.py            # median of 3 runs per command
    .venv/bin/python benchmarks/cold_start.py --runs 5

For each command: the median wall time and CPU time (user + system, the process and its children), and
the same with Python barred from keeping compiled bytecode (PYTHONDONTWRITEBYTECODE=1 over an install made
with --no-compile, as a shell that sets it gets: every import compiles its module from source; the Makefile
unexports it).  Goal (issue 35): each `--help` under 1 s on a quiet machine.  Where the time goes:
`python -X importtime -m qr.filter --help`.
"""

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

QR = str(Path(sys.executable).with_name("qr"))
COMMANDS = [[QR, "--help"], [QR, "diagnose", "--help"], [QR, "filter", "--help"], [QR, "learn", "--help"],
            [QR, "simulate", "--help"], [sys.executable, "-m", "qr.filter", "--help"]]


def once(cmd, env) -> tuple[float, float]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, check=True, capture_output=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    runs = ap.parse_args().runs
    cached = {k: v for k, v in os.environ.items() if k not in ("PYTHONDONTWRITEBYTECODE", "PYTHONPYCACHEPREFIX")}
    # Python still reads the bytecode an earlier process left; an empty cache folder stands for an install none
    # was ever written to
    uncached = {**cached, "PYTHONDONTWRITEBYTECODE": "1", "PYTHONPYCACHEPREFIX": tempfile.mkdtemp()}
    print(f"{'command':32s} {'wall s':>7s} {'CPU s':>6s}   {'no bytecode kept: wall s':>24s} {'CPU s':>6s}")
    for cmd in COMMANDS:
        once(cmd, cached)  # the bytecode written once, as the first run after an install does
        rows = []
        for env in (cached, uncached):
            t = [once(cmd, env) for _ in range(runs)]
            rows.append((statistics.median(w for w, _ in t), statistics.median(c for _, c in t)))
        name = " ".join(["qr" if cmd[0] == QR else "python -m", *cmd[1 if cmd[0] == QR else 2:]])
        print(f"{name:32s} {rows[0][0]:7.2f} {rows[0][1]:6.2f}   {rows[1][0]:24.2f} {rows[1][1]:6.2f}")
    print(f"(load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")


if __name__ == "__main__":
    main()
