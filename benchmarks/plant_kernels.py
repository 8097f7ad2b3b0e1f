"""The compiled plant's kernels on one synthetic flight: what the named plant state (qr.plant_state) must not slow.

    .venv/bin/python benchmarks/plant_kernels.py [--repeats 5] [--threads 1] [--only rollout,synth]

Flies a 60 s, 100 Hz synthetic Crazyflie flight with several effects (qr synth's loop at 1 kHz), then times,
each the best of ``--repeats`` after a warm-up (numba's compile and cache load not counted):
``synth``, the simulation loop; ``rollout``, ``qr evaluate``'s compiled rollout of the extended plant at
H = 50 over every start (qr.rollout.score_plant); ``bands``, the Monte Carlo band's spread of 8 draws
(qr.bands.spread); ``torch``, the differentiable twin's rollout of 256 windows (qr.rollout_torch).
Prints one line per kernel: best and median wall time.  Runs on any checkout (``PYTHONPATH=OTHER/src``
to time another one with the same interpreter).
"""

import argparse
import os
import statistics
import time

os.environ.setdefault("QR_TRACKING", "off")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1, help="numba threads (the rollout's chunks)")
    ap.add_argument("--only", default="synth,rollout,bands,torch", help="the kernels to time (comma-separated)")
    a = ap.parse_args()
    import numba
    import numpy as np
    import torch

    numba.set_num_threads(a.threads)
    torch.set_num_threads(1)
    from qr import bands, rollout, rollout_torch as rt
    from qr.effects import parse_effect_spec
    from qr.sim import plant as pl
    from qr.sim.synth import SynthConfig, simulate_truth
    from qr.vehicle import load_vehicle

    cf = load_vehicle("conf/vehicle/crazyflie21_brushless.yaml")
    eff = [parse_effect_spec(s) for s in ("linear_drag:kx=0.01,ky=0.01,kz=0.005", "cg_offset:rx=0.001,ry=-0.0005",
                                          "marker_offset:rx=0.005,ry=0,rz=0.01", "rotor_drag_moment:k=1e-9",
                                          "ground_effect:k=0.002")]
    cfg = SynthConfig(duration=60, rate=100, seed=3)

    def timed(name, fn):
        if name not in a.only.split(","):
            return
        fn()  # compile or load the cache
        ts = []
        for _ in range(a.repeats):
            t0 = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t0)
        print(f"{name:8s} best {min(ts) * 1e3:9.1f} ms   median {statistics.median(ts) * 1e3:9.1f} ms")

    truth = simulate_truth(cf, eff, cfg)
    timed("synth", lambda: simulate_truth(cf, eff, cfg))
    H = 50
    w = rollout.windows(truth, truth, H, 2)
    P = pl.true_params(cf, eff)
    timed("rollout", lambda: rollout.score_plant(w, H, P, rollout.MODEL))
    rng = np.random.default_rng(0)
    Ps = np.stack([P] + [P * np.where(np.arange(len(P)) < 4, 1 + 0.01 * rng.normal(size=len(P)), 1.0)
                         for _ in range(8)])
    sub = w.scored_at(np.arange(0, len(w.t) - H - 1, 10))
    timed("bands", lambda: bands.spread([sub], Ps, H))
    starts = np.arange(0, 256 * 20, 20)
    j = starts[:, None] + np.arange(1, H + 1)
    X0, U = torch.as_tensor(w.X0[starts]), torch.as_tensor(w.U[j - 1])
    dt = torch.as_tensor(w.t[j] - w.t[j - 1])
    Pt = torch.as_tensor(P)
    timed("torch", lambda: rt.rollout(X0, U, dt, Pt))


if __name__ == "__main__":
    main()
