"""Where `make test`'s CPU goes: the suite run as `make test` runs it, each test's CPU time measured.

    .venv/bin/python benchmarks/test_cpu.py                       # the whole suite (-n 2 --dist loadgroup)
    .venv/bin/python benchmarks/test_cpu.py tests/diagnose -n 0   # any pytest arguments instead
    QR_TEST_CPU_TOP=80 .venv/bin/python benchmarks/test_cpu.py    # the 80 costliest tests (default 25)

On 2 cores the suite is CPU-bound (user + system CPU / wall ≈ 1.96 on a quiet machine), so its wall
time is its CPU time over two: CPU, not wall, says what a cut saves, and it hardly depends on the
machine's load.  A test's CPU is its process's and its reaped child processes' (a Snakemake run and
its jobs count to the test that started it).  Prints the CPU per test module and the costliest tests.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PLUGIN = '''
import json, os, resource, time
import pytest

_rows = []

def _cpu():
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime

@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    t, c = time.time(), _cpu()
    yield
    _rows.append((item.nodeid, _cpu() - c, time.time() - t, t))

def pytest_sessionfinish(session):
    out = os.path.join(os.environ["QR_TEST_CPU_DIR"], os.environ.get("PYTEST_XDIST_WORKER", "main") + ".json")
    with open(out, "w") as f:
        json.dump(_rows, f)
'''


def main() -> None:
    args = sys.argv[1:] or ["-n", "2", "--dist", "loadgroup"]
    with tempfile.TemporaryDirectory() as tmp:
        Path(tmp, "qr_test_cpu.py").write_text(PLUGIN)
        env = dict(os.environ, QR_TEST_CPU_DIR=tmp, PYTHONPATH=os.pathsep.join(filter(None, [tmp, os.environ.get("PYTHONPATH")])))
        env.pop("PYTHONDONTWRITEBYTECODE", None)  # as `make test` (the Makefile unexports it)
        t = time.monotonic()
        rc = subprocess.call([str(ROOT / ".venv" / "bin" / "pytest"), "-q", "-p", "qr_test_cpu", "-p", "no:cacheprovider",
                              *args], cwd=ROOT, env=env)
        wall = time.monotonic() - t
        workers = {f.stem: json.loads(f.read_text()) for f in Path(tmp).glob("*.json")}
        rows = [r for w in workers.values() for r in w]
    total = sum(r[1] for r in rows)
    print(f"\npytest exit {rc}: {len(rows)} tests, {total:.0f} s of CPU in {wall:.0f} s of wall "
          f"({total / max(wall, 1e-9):.2f} cores busy on average)\n")
    # a worker that has run its last test waits for the other: cores idle that no cut of CPU recovers
    ends = {w: max(r[3] + r[2] for r in rs) for w, rs in workers.items() if rs}
    if len(ends) > 1:
        last = max(ends.values())
        print("idle at the end: " + ", ".join(f"{w} {last - e:.0f} s" for w, e in sorted(ends.items())) + "\n")
    by_module = Counter()
    for node, cpu, *_ in rows:
        by_module[node.split("::")[0]] += cpu
    print("| CPU (s) | share | test module |\n|---:|---:|:---|")
    for module, cpu in by_module.most_common(25):
        print(f"| {cpu:.1f} | {100 * cpu / total:.1f} % | {module} |")
    print("\n| CPU (s) | wall (s) | test |\n|---:|---:|:---|")
    for node, cpu, w, _ in sorted(rows, key=lambda r: -r[1])[:int(os.environ.get("QR_TEST_CPU_TOP", 25))]:
        print(f"| {cpu:.1f} | {w:.1f} | {node} |")


if __name__ == "__main__":
    main()
