"""Fit times of the thesis's two learners on 1500 samples (thesis §3.3: ANN 10.33 s, GPR 87.07 s).

    .venv/bin/python benchmarks/train.py

Data: a 60 s synthetic Hummingbird flight with linear drag hidden, noise-free states plus label noise;
the thesis's window (samples 1500-3000).  ANN: Table 4.2 model 8 (v_b, u -> f_a, 2 x 3 linear) trained
on the window's 70 % with early stopping on the next 15 %, as the thesis; GPR: squared-exponential ARD
kernel with the linear basis (Chapter 3) on all 1500 samples, hyperparameters from the default
``hyper_subset`` (300, evenly spaced); a last line times the same fit with hyperparameters from all 1500
samples.  One thread; the median of three fits, after the one-time imports (printed separately).
Targets: ANN < 2 s, GPR < 20 s.
"""

import os
import statistics
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402


def data():
    from qr import datasets
    from qr.effects import parse_effect_spec
    from qr.sim.synth import SynthConfig, simulate_truth
    from qr.vehicle import load_vehicle

    vehicle = load_vehicle("asctec_hummingbird")
    truth = simulate_truth(vehicle, [parse_effect_spec("linear_drag:kx=0.3,ky=0.3,kz=0.1")],
                           SynthConfig(duration=60.0, seed=1))
    table = datasets.flight_table(truth, vehicle, "bench")
    rng = np.random.default_rng(0)
    table[datasets.target_columns("f_a")] += 0.05 * rng.normal(size=(len(table), 3))
    return table.iloc[1500:3000].reset_index(drop=True)


def timed(fn, repeats=3):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main():
    from qr import datasets, models

    window = data()
    t0 = time.perf_counter()
    models.prepare("ann")
    models.prepare("gpr")
    print(f"one-time imports (torch, scikit-learn): {time.perf_counter() - t0:.2f} s")
    X, y = datasets.xy(window, ["v_b", "u"], "f_a")
    ann = {"layers": 2, "neurons": 3, "activation": "linear"}
    t = timed(lambda: models.fit("ann", X[:1050], y[:1050], ann, val=(X[1050:1275], y[1050:1275])))
    print(f"ANN fit, 1500-sample window (v_b,u -> f_a, 2x3 linear, L-BFGS): {t:.2f} s "
          f"(thesis 10.33 s; target < 2 s)")
    X, y = datasets.xy(window, ["v_b"], "f_a")
    t = timed(lambda: models.fit("gpr", X, y, {"kernel": "se_ard", "mean": "ridge"}))
    print(f"GPR fit, 1500 samples (v_b -> f_a, se_ard + basis [1, v_b], 3 axes): {t:.2f} s "
          f"(thesis 87.07 s; target < 20 s)")
    t = timed(lambda: models.fit("gpr", X, y, {"kernel": "se_ard", "mean": "ridge", "hyper_subset": 1500}), 1)
    print(f"GPR fit as above, hyperparameters from all 1500 samples (hyper_subset=1500): {t:.2f} s (for reference)")


if __name__ == "__main__":
    main()
