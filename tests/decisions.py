"""The same decisions on another machine: a diagnosis run again in a fresh process under another OpenBLAS
kernel and numba thread count must name the same set with the same parameters (1e-6 relative).

CI may run on a processor whose OpenBLAS kernel rounds sums differently (SkylakeX on AVX-512 machines,
Haswell, or the generic Prescott), and with another thread count.  The in-process diagnosis of a test
runs with this machine's default kernel and, under xdist, one numba thread (conftest); the repeat runs
with two threads and another kernel, chosen per case in turn from the ones this processor can run.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest


def _cpu_has(flag: str) -> bool:
    try:
        return flag in Path("/proc/cpuinfo").read_text()
    except OSError:
        return False


def _default_kernel() -> str | None:
    from threadpoolctl import threadpool_info

    return next((x.get("architecture") for x in threadpool_info() if x.get("internal_api") == "openblas"), None)


# Prescott (SSE3, OpenBLAS calls it Katmai's kernels) runs anywhere; SkylakeX needs AVX-512
KERNELS = [k for k in (("SkylakeX",) if _cpu_has("avx512f") else ()) + ("Haswell", "Prescott")
           if k != _default_kernel()]


def other_machine(case: int) -> dict:
    """The environment of the repeat of case ``case``: another kernel (in turn) and two numba threads."""
    return {**os.environ, "OPENBLAS_CORETYPE": KERNELS[case % len(KERNELS)], "NUMBA_NUM_THREADS": "2",
            "QR_TRACKING": "off"}


def diagnose_elsewhere(flights, vehicle, out, overrides=(), case: int = 0) -> dict:
    """``qr diagnose`` in a fresh process on another machine's arithmetic; its diagnosis.json."""
    cmd = [sys.executable, "-m", "qr.cli", "diagnose", *map(str, flights), "--vehicle", str(vehicle), "--out", str(out),
           *overrides]
    r = subprocess.run(cmd, env=other_machine(case), capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return json.loads((Path(out) / "diagnosis.json").read_text())


def assert_same_decisions(here: dict, there: dict, rel: float = 1e-6) -> None:
    """The same named set, each parameter equal to ``rel`` (relative to its size, or to its s.e. where the
    parameter is near zero), and the same vehicle-file statements."""
    names = [e["name"] for e in here["effects"]]
    assert names == [e["name"] for e in there["effects"]], (names, there["effects"], there["selection"]["path"])
    for a, b in zip(here["effects"], there["effects"]):
        for k, v in a["parameters"].items():
            scale = max(abs(v), a["stderr"].get(k) or 0.0, 1e-300)
            assert abs(b["parameters"][k] - v) <= rel * scale, (a["name"], k, v, b["parameters"][k])
    assert [c["key"] for c in here.get("vehicle_file", [])] == [c["key"] for c in there.get("vehicle_file", [])]


needs_two_kernels = pytest.mark.skipif(not KERNELS, reason="no other OpenBLAS kernel to compare with")
