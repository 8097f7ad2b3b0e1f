"""Filter throughput: filterpy reference path vs compiled fast path, and a 1-hour flight on one core.

    .venv/bin/python benchmarks/filters.py [--reference-seconds 60] [--skip-hour]

Prints samples per second of the three filters together (position KF, attitude
ESKF, four rotor KFs; forward pass, thesis matrices) for both paths on a
10-minute 400 Hz `qr synth` flight, and their ratio; then the fast path with
the RTS smoother; then the time to filter a 1-hour 400 Hz flight (all three
filters) on one core.  The reference path is a Python loop with constant cost
per sample, so by default it runs on the flight's first ``--reference-seconds``
(pass 600 for all of it, ~15 min).  Compilation is done before timing
(numba caches it on disk).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")  # one core
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

from pathlib import Path  # noqa: E402

from qr.estimation import attitude_eskf, motor_kf, position_kf  # noqa: E402
from qr.sim.synth import SynthConfig, synthesize  # noqa: E402
from qr.vehicle import load_vehicle  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RATE = 400.0


def arrays(flight):
    return (flight["t"].to_numpy(), flight[["px", "py", "pz"]].to_numpy(), flight[["qw", "qx", "qy", "qz"]].to_numpy(),
            flight[["u1", "u2", "u3", "u4"]].to_numpy())


def run_all(path, t, P, Q, U, smooth, speed_scale, progress=False):
    """Seconds per filter (position, attitude, rotors) for ``path`` in {fast, reference}."""
    kw = {"progress": progress} if path == "reference" else {}
    out = {}
    for name, fn, meas, extra in (
            ("position", position_kf, P, {}),
            ("attitude", attitude_eskf, Q, {}),
            ("rotors", motor_kf, U, {"speed_scale": speed_scale})):
        f = fn.filter_reference if path == "reference" else fn.filter_fast
        start = time.perf_counter()
        f(t, meas, fn.THESIS_Q if name != "attitude" else attitude_eskf.THESIS_Q, fn.THESIS_R, "thesis", smooth,
          **extra, **kw)
        out[name] = time.perf_counter() - start
    return out


def fmt(seconds):
    return ", ".join(f"{k} {v:.2f} s" for k, v in seconds.items())


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reference-seconds", type=float, default=60.0)
    ap.add_argument("--skip-hour", action="store_true")
    args = ap.parse_args()
    vehicle = load_vehicle(ROOT / "conf" / "vehicle" / "asctec_hummingbird.yaml")
    start = time.perf_counter()
    flight, _ = synthesize(vehicle, [], SynthConfig(duration=600.0, rate=RATE, seed=1))
    print(f"10-minute flight at {RATE:.0f} Hz: {len(flight)} samples (synthesised in "
          f"{time.perf_counter() - start:.1f} s)")
    t, P, Q, U = arrays(flight)
    hover = vehicle.hover_speed
    run_all("fast", t[:500], P[:500], Q[:500], U[:500], False, hover)  # compile / load the numba cache
    run_all("fast", t[:500], P[:500], Q[:500], U[:500], True, hover)

    fast = run_all("fast", t, P, Q, U, False, hover)
    fast_rate = len(t) / sum(fast.values())
    n_ref = min(len(t), int(args.reference_seconds * RATE) + 1)
    ref = run_all("reference", t[:n_ref], P[:n_ref], Q[:n_ref], U[:n_ref], False, hover, progress=True)
    ref_rate = n_ref / sum(ref.values())
    smooth = run_all("fast", t, P, Q, U, True, hover)
    smooth_rate = len(t) / sum(smooth.values())
    print(f"reference (filterpy), forward, first {n_ref} samples: {ref_rate:12,.0f} samples/s   ({fmt(ref)})")
    print(f"fast (numba), forward, all {len(t)} samples:    {fast_rate:12,.0f} samples/s   ({fmt(fast)})")
    print(f"ratio fast / reference: {fast_rate / ref_rate:.0f}x   (target >= 20x)")
    print(f"fast, forward + RTS smoother:                {smooth_rate:12,.0f} samples/s   ({fmt(smooth)})")

    if args.skip_hour:
        return
    start = time.perf_counter()
    hour, _ = synthesize(vehicle, [], SynthConfig(duration=3600.0, rate=RATE, seed=2))
    print(f"\n1-hour flight at {RATE:.0f} Hz: {len(hour)} samples (synthesised in {time.perf_counter() - start:.1f} s)")
    th, Ph, Qh, Uh = arrays(hour)
    cpu = time.process_time()
    hour_fast = run_all("fast", th, Ph, Qh, Uh, False, hover)
    print(f"all three filters, fast path, one core: {sum(hour_fast.values()):.1f} s wall, "
          f"{time.process_time() - cpu:.1f} s CPU   ({fmt(hour_fast)})   (target < 60 s)")
    hour_smooth = run_all("fast", th, Ph, Qh, Uh, True, hover)
    print(f"  with the RTS smoother: {sum(hour_smooth.values()):.1f} s   ({fmt(hour_smooth)})")


if __name__ == "__main__":
    main()
