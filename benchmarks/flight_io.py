"""Writing and reading a canonical flight, CSV (every float's shortest round-trip decimal) and Parquet.

    .venv/bin/python benchmarks/flight_io.py [--minutes 10] [--rate 100]

Prints, for a `qr synth` flight of the given length (its stamps shifted to epoch time, ~1.7e9 s), the
time `qr.flight.write_flight` takes to write it as CSV and as Parquet, the time `qr.flight.read_flight`
takes to read each back (validation included), and the file sizes; and, for comparison, the CSV at the
nine significant digits qr wrote before (which lost epoch stamps' sub-10-second part).  Median of three.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import pandas as pd

from qr.flight import read_flight, write_flight
from qr.sim.synth import SynthConfig, synthesize
from qr.vehicle import load_vehicle

ROOT = Path(__file__).resolve().parents[1]


def median_time(fn, repeat=3) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=100.0)
    a = ap.parse_args()
    vehicle = load_vehicle(ROOT / "conf" / "vehicle" / "asctec_hummingbird.yaml")
    flight, _ = synthesize(vehicle, [], SynthConfig(duration=60 * a.minutes, rate=a.rate, seed=0))
    flight["t"] = flight["t"] + 1.7e9
    print(f"flight: {len(flight)} rows x {flight.shape[1]} columns ({a.minutes:g} min at {a.rate:g} Hz), epoch stamps")
    with tempfile.TemporaryDirectory() as d:
        for name in ("flight.csv", "flight.parquet"):
            path = Path(d) / name
            w = median_time(lambda: write_flight(flight, path))
            r = median_time(lambda: read_flight(path))
            print(f"{name:15s} write {w:6.2f} s   read {r:6.2f} s   {path.stat().st_size / 1e6:7.1f} MB")
        old = Path(d) / "nine_digits.csv"
        w = median_time(lambda: flight.to_csv(old, index=False, float_format="%.9g"))
        distinct = pd.read_csv(old)["t"].nunique()
        print(f"{'CSV at %.9g':15s} write {w:6.2f} s   {old.stat().st_size / 1e6:7.1f} MB, lossy: {distinct} distinct "
              f"stamps of {len(flight)} read back")


if __name__ == "__main__":
    main()
