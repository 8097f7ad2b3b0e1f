"""How many times numba compiles the filters' and the rollout's kernels for one flight read two ways.

    .venv/bin/python benchmarks/kernel_variants.py

A fresh checkout has no numba cache: every kernel is compiled on first use, once per argument type.  A
frame built in memory (a test's synthetic flight) and the same frame read back from Parquet (the workflow's
flights) hand the kernels differently laid-out arrays (C order vs read-only Fortran columns); unless the
arrays are brought to one type first (``qr.linalg_compiled.kernel_array``), each kind is a further
compilation of the same kernel.  Runs in a scratch numba cache (NUMBA_CACHE_DIR), so that it measures
a fresh checkout whatever the repository's cache holds; prints the compilations and their CPU seconds
per pass.  The numbers a pass computes are compared between the two readings (they must be equal).
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    if "NUMBA_CACHE_DIR" not in os.environ:  # a cold cache of our own: run again in a fresh process
        with tempfile.TemporaryDirectory() as cache:
            os.execve(sys.executable, [sys.executable, __file__], {**os.environ, "NUMBA_CACHE_DIR": cache})
    import numpy as np
    import pandas as pd
    from numba.core import event

    compiles: list[tuple[str, float]] = []
    depth: list[float] = []

    class Count(event.Listener):  # outermost compilations only (a kernel's callees are compiled inside it)
        def on_start(self, ev):
            depth.append(time.process_time())

        def on_end(self, ev):
            t0 = depth.pop()
            if not depth:
                compiles.append((ev.data["dispatcher"].py_func.__qualname__, time.process_time() - t0))

    event.register("numba:compile", Count())

    from qr.estimation import estimate
    from qr.rollout import score
    from qr.sim.synth import SynthConfig, synthesize
    from qr.vehicle import load_vehicle

    vehicle = load_vehicle(ROOT / "conf" / "vehicle" / "asctec_hummingbird.yaml")
    built, _ = synthesize(vehicle, [], SynthConfig(duration=20.0, rate=100.0, seed=5))
    with tempfile.TemporaryDirectory() as tmp:
        built.to_parquet(Path(tmp) / "f.parquet")
        read = pd.read_parquet(Path(tmp) / "f.parquet")
        results = []
        for name, flight in (("built in memory", built), ("read from Parquet", read)):
            n0 = len(compiles)
            states, _ = estimate(flight, vehicle, {})
            states.to_parquet(Path(tmp) / "s.parquet")
            if name == "read from Parquet":
                states = pd.read_parquet(Path(tmp) / "s.parquet")
            sums = score(states, flight, 50, 5, {"nominal": (vehicle, [])})["nominal"][0]
            results.append((states.drop(columns=[c for c in states if "time" in c]).to_numpy(float), sums))
            new = compiles[n0:]
            print(f"{name}: {len(new)} compilations, {sum(c for _, c in new):.1f} s of CPU"
                  + (f" ({', '.join(f'{n} {c:.1f}' for n, c in new)})" if new else ""))
    same = all(np.array_equal(a, b, equal_nan=True) for a, b in zip(results[0], results[1]))
    print(f"the two readings give the same numbers: {same}")


if __name__ == "__main__":
    main()
