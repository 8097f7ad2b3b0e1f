"""`qr replay`: wall-clock time from the shell, and the Lee controller against the firmware's logged outputs.

    .venv/bin/python benchmarks/replay.py              # time: a 9.2 s Crazyflie log, 1 and 4 vehicle files
    .venv/bin/python benchmarks/replay.py --firmware   # the 25 payload figure-8 flights: controller vs firmware

Time: `qr replay` in a fresh process, as a user runs it (imports, reading the raw log, finding the setpoints,
flying, the report and figure), the median of three runs, wall and CPU time, with one vehicle file and with
four (each extra vehicle's cost is the difference over three).  Target (issue 34): a 10 s flight in <= 2 s
per vehicle from the shell.  The load average is printed beside: a figure taken while other jobs share the
cores is marked "under load".  Numba kernels are compiled (and cached) by a warm-up run first.

Firmware: tests/replay/firmware_logs.py's comparison on every payload figure-8 flight (docs/replay.md's table).
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

os.environ.setdefault("QR_TRACKING", "off")
ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("QR_DATA", ROOT.parent / "shared" / "data" / "imrclab-crazyflie"))
FIGURE8 = DATA.parent / "crazyswarm2-figure8" / "figure8.csv"
LOG = DATA / "brushless_flights" / "data" / "eckart00"  # 9.2 s, TIMESCALE 1.0
PAYLOAD = {1.0: [6, 7, 8, 9, 10], 0.9: [11, 12, 13, 14, 15], 0.8: [17, 18, 19, 20, 21], 0.7: [22, 24, 26, 27, 28],
           0.6: [29, 30, 32, 33, 34]}


def load() -> str:
    one = os.getloadavg()[0]
    cores = os.cpu_count() or 1
    return f"load average {one:.1f} on {cores} cores" + (" (under load)" if one > 0.5 * cores else "")


def shell(tmp: Path, vehicles: list[str], runs: int = 3) -> tuple[float, float]:
    qr = str(Path(sys.executable).with_name("qr"))
    walls, cpus = [], []
    for k in range(runs):
        out = tmp / f"out-{len(vehicles)}-{k}"
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([qr, "replay", str(LOG), *[a for v in vehicles for a in ("--vehicle", v)], "--controller", "lee",
                        "--out", str(out), f"replay.trajectory={FIGURE8}"], check=True, capture_output=True)
        walls.append(time.perf_counter() - t0)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
    return statistics.median(walls), statistics.median(cpus)


def timing() -> None:
    cf = str(ROOT / "conf" / "vehicle" / "crazyflie21_brushless.yaml")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        four = []
        for i, effects in enumerate(([], ["linear_drag:kx=0.013,ky=0.013,kz=0.01"], ["yaw_torque_gain:gain=0.2"])):
            path = tmp / f"v{i}.yaml"
            text = (ROOT / "conf" / "vehicle" / "crazyflie21_brushless.yaml").read_text()
            if effects:
                name, params = effects[0].split(":")
                kv = ", ".join(f"{k}: {v}" for k, v in (p.split("=") for p in params.split(",")))
                text += f"effects:\n  - {{name: {name}, parameters: {{{kv}}}}}\n"
            path.write_text(text)
            four.append(str(path))
        four.append(cf)
        shell(tmp, [cf], runs=1)  # warm-up: numba's cache
        w1, c1 = shell(tmp, [cf])
        w4, c4 = shell(tmp, four)
        print(f"qr replay of a 9.2 s log from the shell ({load()}):")
        print(f"  1 vehicle:  {w1:.2f} s wall, {c1:.2f} s CPU (median of 3)")
        print(f"  4 vehicles: {w4:.2f} s wall, {c4:.2f} s CPU; each vehicle after the first {(w4 - w1) / 3:.2f} s")
        print(f"  per vehicle with 4: {w4 / 4:.2f} s (goal <= 2 s for a 10 s flight)")


def firmware() -> None:
    import numpy as np

    sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "replay")]
    from firmware_logs import reproduce

    rows = []
    print("flight    scale  torque from logged refs (% of spread x/y/z)  thrust (%)  R_d (deg)  gains (max dev %)")
    for s, flights in PAYLOAD.items():
        for i in flights:
            r = reproduce(DATA / "brushless_flights_payload" / "data" / f"eckart{i:02d}", s)
            rows.append(r)
            refs = 100 * r["torque_refs_rms"] / r["torque_spread"]
            print(f"eckart{i:02d}  {s:4.1f}   {refs[0]:5.2f} {refs[1]:5.2f} {refs[2]:5.2f}"
                  f"{100 * r['thrust_rms'] / r['thrust_spread']:28.2f}{r['attitude_ref_rms_deg']:11.3f}"
                  f"{100 * np.abs(r['fitted_gains'] / r['gains'] - 1).max():12.2f}")
    refs = np.array([100 * r["torque_refs_rms"] / r["torque_spread"] for r in rows])
    thrust = np.array([100 * r["thrust_rms"] / r["thrust_spread"] for r in rows])
    print(f"torques: median {np.round(np.median(refs, 0), 2)} %, max {np.round(refs.max(0), 2)} %; thrust "
          f"{thrust.min():.2f}-{thrust.max():.2f} %; R_d {min(r['attitude_ref_rms_deg'] for r in rows):.2f}-"
          f"{max(r['attitude_ref_rms_deg'] for r in rows):.2f} deg")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--firmware", action="store_true", help="the controller against the 25 payload flights' logs")
    a = ap.parse_args()
    firmware() if a.firmware else timing()
