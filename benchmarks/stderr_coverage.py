"""Are the standard errors honest?  Coverage of the block-bootstrap s.e. per effect family.

    .venv/bin/python benchmarks/stderr_coverage.py                 # 20 flights per family, 60 s at 100 Hz
    .venv/bin/python benchmarks/stderr_coverage.py --flights 30 --duration 30

For each mechanism family (qr.sim.scenarios.FAMILIES) and seed: one effect of the family, drawn in
the benchmark's stated ranges, hidden in a synthetic flight (vehicle alternating Hummingbird /
Crazyflie, noise 0.5-2x the default); the diagnosis fits it (``diagnose.candidates=[effect]``: the
estimator, not the selection, is under test) and reports each parameter with its s.e.  Printed per
family: the share of parameters whose true value lies within 2 s.e. of the estimate (goal >= 85 %;
95 % for a Gaussian estimator without bias) and the median |error| / s.e.  A flight on which the
effect is too small to be named has no s.e.: it is counted apart ("not named").
"""

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("QR_TRACKING", "off")

import numpy as np  # noqa: E402

from qr.sim.scenarios import FAMILIES, coverage_cases, z_scores  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--flights", type=int, default=20)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--family", default="", help="only this family")
    a = ap.parse_args()
    t_all = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for fam in FAMILIES:
            if a.family and fam != a.family:
                continue
            z = []
            for case in coverage_cases(fam, a.flights):
                z += z_scores(case, Path(d), a.duration)
            z = np.array(z)
            missed = int(np.sum(~np.isfinite(z)))
            z = z[np.isfinite(z)]
            cover = float(np.mean(np.abs(z) <= 2))
            rows.append((fam, len(z), cover))
            print(f"{fam:20s} {len(z):4d} parameters: within 2 s.e. {cover:5.0%} (goal >= 85 %), "
                  f"median |error|/s.e. {np.median(np.abs(z)):.2f}, worst {np.max(np.abs(z)):.1f}; "
                  f"not named: {missed}", flush=True)
    print(f"\n{sum(r[1] for r in rows)} parameters, {time.perf_counter() - t_all:.0f} s; families below 85 %: "
          f"{', '.join(r[0] for r in rows if r[2] < 0.85) or 'none'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
