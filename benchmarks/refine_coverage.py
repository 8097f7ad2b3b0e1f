"""Coverage of the refinement's standard errors (qr.diagnose.refine) on synthetic flights.

    .venv/bin/python benchmarks/refine_coverage.py                  # 8 flights at 500 Hz, 12 s
    .venv/bin/python benchmarks/refine_coverage.py --rate 100 --duration 20 --horizon 50 --stride 5

Hummingbird flights with J_xx × 1.5 hidden (``qr synth``, default noise: 0.5 % rotor-speed noise),
filtered as the diagnosis filters them, the first 70 % refined from the vehicle file: per flight the
estimate of J_xx with its standard error, then the share of flights whose ±2 s.e. interval holds the
truth, the estimates' spread over the mean s.e. and their mean error over the mean s.e. (a bias the
standard errors do not hold).  ``--no-correction``: without the errors-in-variables correction.
"""

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("QR_TRACKING", "off")

import numpy as np  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rate", type=float, default=500)
    ap.add_argument("--duration", type=float, default=12)
    ap.add_argument("--horizon", type=int, default=100)
    ap.add_argument("--stride", type=int, default=25)
    ap.add_argument("--flights", type=int, default=8)
    ap.add_argument("--no-correction", action="store_true")
    a = ap.parse_args()
    from qr.config import compose, to_dict
    from qr.diagnose.refine import RefineSettings, diagnosis_windows, refine
    from qr.effects import parse_effect_spec
    from qr.flight import read_flight
    from qr.rollout import EvaluateConfig
    from qr.sim.synth import SynthConfig, write_synth
    from qr.pieces import rollout_pieces
    from qr.vehicle import load_vehicle

    v = load_vehicle("conf/vehicle/asctec_hummingbird.yaml")
    filt = to_dict(compose(["filter=auto"]))["filter"]
    truth = 0.007 * 1.5
    rows = []
    tmp = Path(tempfile.mkdtemp(prefix="qr-refine-"))
    print(f"{a.flights} flights, {a.duration:g} s at {a.rate:g} Hz, H = {a.horizon}, every {a.stride}th start; "
          f"J_xx true {truth:g} kg m²")
    for seed in range(1, a.flights + 1):
        d = tmp / f"f{seed}"
        write_synth(d, v, [parse_effect_spec("inertia_error:dJxx=0.0035,dJyy=0,dJzz=0")],
                    SynthConfig(duration=a.duration, rate=a.rate, seed=seed))
        st, ms = zip(*[(s, m) for s, m, _ in rollout_pieces([d / "flight.csv"], [read_flight(d / "flight.csv")], v,
                                                            EvaluateConfig(horizon=a.horizon), filt)[0]])
        t = st[0]["t"].to_numpy()
        cut = t[0] + 0.7 * (t[-1] - t[0])
        train, test, noise = diagnosis_windows(list(st), list(ms), [0] * len(st),
                                               [{"train": [t[0], cut], "test": [cut + 0.5, t[-1]]}], a.horizon, 2, 0.5)
        t0 = time.perf_counter()
        r = refine(train, test, v, [], RefineSettings(horizon=a.horizon, stride=a.stride),
                   None if a.no_correction else noise)
        p = r.parameters[0]
        rows.append((p.total(p.rollout), p.rollout_se))
        print(f"flight {seed}: J_xx {p.total(p.rollout):.6g} ± {p.rollout_se:.2g} (z {(p.total(p.rollout) - truth) / p.rollout_se:+.2f}), "
              f"{r.windows} windows, {time.perf_counter() - t0:.1f} s")
    est, se = np.array(rows).T
    print(f"\n±2 s.e. holds the truth: {np.mean(np.abs(est - truth) <= 2 * se):.0%} of {len(est)} flights; "
          f"spread / mean s.e. {est.std(ddof=1) / se.mean():.2f}; mean error / mean s.e. "
          f"{(est.mean() - truth) / se.mean():+.2f} ({100 * (est.mean() / truth - 1):+.2f} % of J_xx)")


if __name__ == "__main__":
    main()
