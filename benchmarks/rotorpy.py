"""What does `qr diagnose` name on flights RotorPy simulates?  Each of RotorPy's aerodynamic terms alone,
all together, and none.

    .venv/bin/python benchmarks/rotorpy.py               # 8 configurations x 3 seeds, 2 x 30 s flights each (~12 min)
    .venv/bin/python benchmarks/rotorpy.py --seeds 1 --duration 20

RotorPy's own Hummingbird (rotorpy/vehicles/hummingbird_params.py) flown by its SE3Control along two of
its 3-D circles per run (radii 1-2.5 m, frequencies 0.1-0.3 Hz, drawn from the seed; peak speeds
1-3.5 m/s), logged at 100 Hz with qr's synthetic noise (qr.sim.rotorpy_flights).  Each configuration
switches on some of RotorPy's terms at its Hummingbird's values (k_d 1.19e-4, k_z 2.32e-4, k_h 3.39e-3,
c_D 0.005 / 0.005 / 0.01) and a flapping coefficient RotorPy's files leave at 0 (k_flap = -1e-5);
RotorPy's motor lag (tau_m 5 ms) is always on.  The expected names go through the export's mapping
(qr.sim.rotorpy_flights.expected_effects): k_d -> rotor_drag and rotor_drag_moment (one k: RotorPy's
H-force at the hubs), k_h -> translational_lift, k_z -> linear_drag kz, k_flap -> blade_flapping,
c_D -> quadratic_drag.  Two of RotorPy's terms have no exact catalog image: k_z's moments at the hubs (a
roll/pitch-rate damping) and the parasitic drag's |v| v_j (qr's quadratic drag is |v_j| v_j per axis);
"all on but k_z" shows the rest together.

Prints per run the expected and the named set and any vehicle-file statement, then per configuration:
the exact-set rate (named set = expected set), the false-name rate (runs naming an effect not expected),
the rate of expected effects named with their parameters within 20 %, the false names seen and the runs
with a vehicle-file statement (RotorPy's coefficients are the file's: any is wrong).
"""

import argparse
import copy
import os
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

# this script's own name is the package's: its folder off the path, or `import rotorpy` finds the script
sys.path = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("QR_TRACKING", "off")

import numpy as np  # noqa: E402

from qr.flight import write_flight  # noqa: E402
from qr.sim.rotorpy_flights import AERO_KEYS, Circle, RotorpyFlight, expected_effects, fly, vehicle_dict  # noqa: E402
from qr.stages.diagnose import run_diagnosis  # noqa: E402
from qr.vehicle import save_vehicle, vehicle_from_dict  # noqa: E402

K_FLAP = -1e-5
CONFIGS = {  # name -> RotorPy aerodynamic keys left on (the others 0); None: aero=False
    "aero off": None,
    "rotor drag k_d": ("k_d",),
    "induced inflow k_z": ("k_z",),
    "flapping k_flap": ("k_flap",),
    "parasitic c_D": ("c_Dx", "c_Dy", "c_Dz"),
    "translational lift k_h": ("k_h",),
    "all on but k_z": tuple(k for k in AERO_KEYS if k != "k_z"),
    "all on": AERO_KEYS,
}
CHECKED = {"rotor_drag": ("k",), "rotor_drag_moment": ("k",), "translational_lift": ("k",), "linear_drag": ("kz",),
           "blade_flapping": ("k",), "quadratic_drag": ("cx", "cy", "cz")}


def params(keys):
    from rotorpy.vehicles.hummingbird_params import quad_params

    qp = copy.deepcopy(quad_params)
    qp["k_flap"] = K_FLAP
    for k in AERO_KEYS:
        if keys is not None and k not in keys:
            qp[k] = 0.0
    return qp


def circles(seed):
    rng = np.random.default_rng([seed, 271])
    return [Circle(radius=(*rng.uniform(1.0, 2.5, 2), rng.uniform(0.2, 0.5)),
                   freq=(*rng.uniform(0.1, 0.3, 2), rng.uniform(0.2, 0.4))) for _ in range(2)]


def run(name, keys, seed, duration, work: Path):
    qp = params(keys)
    flights = []
    for i, c in enumerate(circles(seed)):
        flight, _ = fly(qp, RotorpyFlight(duration=duration, aero=keys is not None, seed=100 * seed + i, trajectory=c))
        flights.append(work / f"f{i}.csv")
        write_flight(flight, flights[-1])
    save_vehicle(vehicle_from_dict(vehicle_dict(qp, "hummingbird-rotorpy")), work / "vehicle.yaml")
    doc = run_diagnosis(flights, work / "vehicle.yaml", work / "diag", [], log=lambda m: None, figures=False)
    named = {e["name"]: e["parameters"] for e in doc["effects"]}
    expected = expected_effects(qp) if keys is not None else {}
    within = {n: all(abs(named[n][p] - expected[n][p]) <= 0.2 * abs(expected[n][p]) for p in CHECKED[n]
                     if expected[n][p]) for n in expected if n in named}
    return expected, named, within, [c["statement"] for c in doc.get("vehicle_file", [])]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--duration", type=float, default=30.0, help="s per flight (two flights per run)")
    a = ap.parse_args()
    t0 = time.time()
    results = {}
    for name, keys in CONFIGS.items():
        for seed in range(a.seeds):
            with tempfile.TemporaryDirectory() as d:
                expected, named, within, said = run(name, keys, seed, a.duration, Path(d))
            results.setdefault(name, []).append((expected, named, within, said))
            print(f"{name:24s} seed {seed}: expected {sorted(expected) or '-'}; named "
                  + (", ".join(f"{n} {named[n]}" for n in named) or "-")
                  + "".join(f"\n    vehicle file: {x}" for x in said), flush=True)
    print(f"\n{a.seeds} seeds x {len(CONFIGS)} configurations, 2 x {a.duration:g} s flights each, "
          f"{time.time() - t0:.0f} s\n")
    print("| RotorPy terms on | exact set | false name | expected named within 20 % | false names seen "
          "| vehicle-file statements |")
    print("|---|---|---|---|---|---|")
    for name, rs in results.items():
        exact = sum(set(n) == set(e) for e, n, _, _ in rs)
        false = sum(bool(set(n) - set(e)) for e, n, _, _ in rs)
        hits = sum(sum(w.values()) for _, _, w, _ in rs)
        total = sum(len(e) for e, _, _, _ in rs)
        seen = Counter(x for e, n, _, _ in rs for x in set(n) - set(e))
        said = sum(bool(s) for *_, s in rs)
        print(f"| {name} | {exact}/{len(rs)} | {false}/{len(rs)} | "
              + (f"{hits}/{total}" if total else "-") + " | "
              + (", ".join(f"{k} ({v})" for k, v in seen.most_common()) or "-") + f" | {said}/{len(rs)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
