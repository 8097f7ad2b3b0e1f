"""Wall-clock time of `qr diagnose` (filtering + identification + replay + report).

    .venv/bin/python benchmarks/diagnose.py            # 90 s at 100 Hz, then 1 h at 400 Hz
    .venv/bin/python benchmarks/diagnose.py --short    # only the 90 s flight

Two figures for the 90 s flight: in-process (a warm process: imports done, the Hydra tree composed once
before) and from the shell, as a user runs it: `qr diagnose` in a fresh process, the median of
three runs, its wall time and CPU time (all threads and the figure child).  The shell figure is the
README's.  Targets: from the shell <= 3 s on a quiet 2-core machine (issue 28); in-process 90 s /
100 Hz within 2 s, 1 h / 400 Hz within 1 min (issue 14; issue 5's: 60 s and 10 min).
Numba kernels are compiled (and cached) by a warm-up run first.
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

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("QR_TRACKING", "off")

from qr.stages.diagnose import run_diagnosis  # noqa: E402
from qr.effects import parse_effect_spec  # noqa: E402
from qr.sim.synth import SynthConfig, write_synth  # noqa: E402
from qr.vehicle import load_vehicle  # noqa: E402


def case(tmp: Path, duration: float, rate: float, tag: str) -> float:
    vehicle = load_vehicle("asctec_hummingbird")
    effects = [parse_effect_spec("linear_drag:kx=0.3,ky=0.3,kz=0.15"), parse_effect_spec("cg_offset:rx=0.01,ry=0")]
    t0 = time.perf_counter()
    write_synth(tmp / tag, vehicle, effects, SynthConfig(duration=duration, rate=rate, seed=1))
    t_synth = time.perf_counter() - t0
    t0 = time.perf_counter()
    doc = run_diagnosis([tmp / tag / "flight.csv"], tmp / tag / "vehicle.yaml", tmp / f"{tag}-out", log=lambda m: None)
    dt = time.perf_counter() - t0
    print(f"{tag:>14}: {duration:6.0f} s at {rate:3.0f} Hz ({int(duration * rate):>9,} samples): "
          f"diagnose {dt:7.1f} s   [synth {t_synth:.1f} s]   named: {', '.join(e['name'] for e in doc['effects'])}")
    return dt


def shell(tmp: Path, tag: str, runs: int = 3) -> tuple[float, float]:
    """``qr diagnose`` of ``tag``'s flight in a fresh process, as from the shell: median wall and CPU (s)."""
    qr = str(Path(sys.executable).with_name("qr"))
    walls, cpus = [], []
    for k in range(runs):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([qr, "diagnose", str(tmp / tag / "flight.csv"), "--vehicle", str(tmp / tag / "vehicle.yaml"),
                        "--out", str(tmp / f"{tag}-shell-{k}")], check=True, capture_output=True)
        walls.append(time.perf_counter() - t0)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
    return statistics.median(walls), statistics.median(cpus)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--short", action="store_true")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        case(tmp, 20, 100, "warm-up")
        inside = case(tmp, 90, 100, "90 s flight")
        wall, cpu = shell(tmp, "90 s flight")
        print(f"{'90 s flight':>14}: from the shell (`qr diagnose`, a fresh process, median of 3): {wall:.1f} s wall, "
              f"{cpu:.1f} s CPU; in-process {inside:.1f} s")
        if not a.short:
            case(tmp, 3600, 400, "1-hour flight")
