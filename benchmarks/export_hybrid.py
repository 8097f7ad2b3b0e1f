"""What a hybrid's export costs: `qr export` in a cold shell, and flying the learned wrench in RotorPy and MuJoCo.

    .venv/bin/python benchmarks/export_hybrid.py

A hybrid file as `qr learn residual` writes it with its default network (13 -> 32 -> 32 -> 6, tanh, inputs
v_b, omega, g_b, u2; seeded untrained weights) on the brushless set's extended model
(tests/export/crazyflie21_brushless_extended.yaml).  Prints: the wall time of `qr export` per simulator (a new
process each, the median of 3); RotorPy's `QrMultirotor.step` over 2 s at 100 Hz (DOP853, RotorPy's default
tolerances) for the extended model and for the hybrid; MuJoCo's 2 s at its 1 ms RK4 without and with the
learned-wrench callback.  Hover rotor speeds throughout (the cost, not the flight, is measured).
"""

import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# this script's folder off the path (benchmarks/rotorpy.py would shadow the rotorpy package)
sys.path = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("QR_TRACKING", "off")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
QR = str(Path(sys.executable).with_name("qr"))


def hybrid(folder: Path) -> Path:
    from qr import residual as rs
    from qr.vehicle import load_vehicle, save_vehicle

    v = load_vehicle(ROOT / "tests" / "export" / "crazyflie21_brushless_extended.yaml")
    rng = np.random.default_rng(0)
    sizes = [13, 32, 32, 6]
    Ws = tuple(rng.normal(0, 1 / np.sqrt(a), (b, a)) for a, b in zip(sizes, sizes[1:]))
    bs = tuple(np.zeros(b) for b in sizes[1:])
    net = rs.Residual(("v_b", "omega", "g_b", "u2"), "tanh", Ws, bs, np.zeros(13), np.ones(13),
                      np.array([0.01, 0.01, 0.01, 1e-5, 1e-5, 1e-6]), v.hover_speed / 0.7)
    rs.save_weights(net, folder / "residual.npz")
    raw = v.to_dict()
    raw["residual"] = rs.block(net, str((folder / "residual.npz").resolve()), "benchmark")
    save_vehicle(raw, folder / "hybrid_vehicle.yaml")
    return folder / "hybrid_vehicle.yaml"


def load(path: Path):
    import importlib.util

    spec = importlib.util.spec_from_file_location(path.stem + str(abs(hash(str(path)))), path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def main():
    tmp = Path(tempfile.mkdtemp(prefix="qr-export-bench-"))
    try:
        run(tmp)
    finally:
        shutil.rmtree(tmp)


def run(tmp: Path):
    path = hybrid(tmp)
    extended = ROOT / "tests" / "export" / "crazyflie21_brushless_extended.yaml"
    print("hybrid: network 13-32-32-6 on the brushless extended model")
    for to in ("rotorpy", "mujoco", "px4-gz"):
        times = []
        for k in range(3):
            t0 = time.perf_counter()
            subprocess.run([QR, "export", str(path), "--to", to, "--out", str(tmp / f"{to}{k}")], check=True,
                           capture_output=True)
            times.append(time.perf_counter() - t0)
        print(f"qr export --to {to}: {statistics.median(times):.2f} s (a new process; median of 3)")
    subprocess.run([QR, "export", str(extended), "--to", "rotorpy", "--out", str(tmp / "rp_ext")], check=True,
                   capture_output=True)

    from qr.export import mapping as mp
    from qr.vehicle import load_vehicle

    v = load_vehicle(path)
    omega = np.full(4, mp.plant_of(v).hover)
    for label, folder in (("extended", tmp / "rp_ext"), ("hybrid", tmp / "rotorpy0")):
        mod = load(folder / "crazyflie21_brushless_params.py")
        quad = mod.QrMultirotor()
        state = mod.hover_state()
        t0 = time.perf_counter()
        for _ in range(200):
            state["rotor_speeds"] = omega.copy()
            state = quad.step(state, {"cmd_motor_speeds": omega.copy()}, 0.01)
        print(f"RotorPy QrMultirotor, 2 s at 100 Hz, {label}: {time.perf_counter() - t0:.2f} s")

    import mujoco

    learned = load(tmp / "mujoco0" / "crazyflie21_brushless_learned_wrench.py")
    model = mujoco.MjModel.from_xml_path(str(tmp / "mujoco0" / "crazyflie21_brushless.xml"))
    for label in ("MJCF alone", "with the callback"):
        data = mujoco.MjData(model)
        data.ctrl[:] = learned.speeds_to_ctrl(omega)
        t0 = time.perf_counter()
        if label == "MJCF alone":
            for _ in range(2000):
                mujoco.mj_step(model, data)
        else:
            with learned.installed(model):
                for _ in range(2000):
                    mujoco.mj_step(model, data)
        print(f"MuJoCo, 2 s at 1 ms RK4, {label}: {time.perf_counter() - t0:.3f} s")


if __name__ == "__main__":
    main()
