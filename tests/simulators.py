"""Flying an export: the same rotor-speed sequence (zero-order hold) through qr's plant and a simulator.

qr's side is the TRUE plant's rigid-body RK4 (:func:`qr.sim.plant.rigid_body_rk4`) with the rotor
speeds held over each log step (``SUBSTEPS`` RK4 steps per log step); RotorPy's is its own
``Multirotor.step`` (scipy's DOP853 at tight tolerances) with the rotor-speed state set to the held
speed and commanded to it, so its motor lag never acts (tau_m -> 0: the measured speeds are the
rotors' own).  States are compared as CG position, attitude angle and body rate.
"""

from __future__ import annotations

import importlib.util
import sys

import numpy as np
from scipy.spatial.transform import Rotation

from qr.sim import plant as pl

SUBSTEPS = 16
TIGHT = {"method": "DOP853", "rtol": 1e-10, "atol": 1e-12}


def load_module(path):
    """Import an exported ``<name>_params.py`` under a unique name."""
    name = f"qr_export_{abs(hash(str(path)))}"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def qr_fly(vehicle, u: np.ndarray, dt: float, x0: np.ndarray) -> np.ndarray:
    """States (len(u) + 1, 13) of qr's plant from ``x0`` (p, v, q scalar first, ω), ``u`` (N, 4) held over each step."""
    P = pl.true_params(vehicle, vehicle.effects)
    x = np.asarray(x0, float).copy()
    out = [x.copy()]
    k, xs, xn, zero = np.empty((4, 13)), np.empty(13), np.empty(13), np.zeros(3)
    h = dt / SUBSTEPS
    for ui in np.asarray(u, float):
        for _ in range(SUBSTEPS):
            pl.rigid_body_rk4(x, ui, ui, ui, P, h, False, zero, k, xs, xn)
            x[:] = xn
        out.append(x.copy())
    return np.array(out)


def rotorpy_state(x0: np.ndarray, omega: np.ndarray) -> dict:
    """qr's state (q scalar first) as RotorPy's dict (q scalar last)."""
    q = x0[6:10]
    return {"x": x0[0:3].copy(), "v": x0[3:6].copy(), "q": np.array([q[1], q[2], q[3], q[0]]),
            "w": x0[10:13].copy(), "wind": np.zeros(3), "rotor_speeds": np.asarray(omega, float).copy()}


def rotorpy_fly(multirotor, omega: np.ndarray, dt: float, x0: np.ndarray) -> np.ndarray:
    """States (len(omega) + 1, 13) of a RotorPy Multirotor, rotor speeds ``omega`` (rad/s) held over each step."""
    state = rotorpy_state(x0, omega[0])
    out = [x0.copy()]
    for w in np.asarray(omega, float):
        state["rotor_speeds"] = w.copy()
        state = multirotor.step(state, {"cmd_motor_speeds": w.copy()}, dt)
        q = state["q"]
        out.append(np.concatenate([state["x"], state["v"], [q[3], q[0], q[1], q[2]], state["w"]]))
    return np.array(out)


def errors(a: np.ndarray, b: np.ndarray) -> dict:
    """Largest position (m), attitude angle (rad) and body-rate (rad/s) difference of two state series."""
    qa = a[:, [7, 8, 9, 6]]
    qb = b[:, [7, 8, 9, 6]]
    angle = (Rotation.from_quat(qa).inv() * Rotation.from_quat(qb)).magnitude()
    return {"p": float(np.max(np.linalg.norm(a[:, 0:3] - b[:, 0:3], axis=1))), "R": float(np.max(angle)),
            "w": float(np.max(np.linalg.norm(a[:, 10:13] - b[:, 10:13], axis=1)))}


def span(a: np.ndarray) -> dict:
    """How far the flight went: largest displacement, rotation from the start and body rate."""
    q = a[:, [7, 8, 9, 6]]
    rot = (Rotation.from_quat(q[:1]).inv() * Rotation.from_quat(q)).magnitude()
    return {"p": float(np.max(np.linalg.norm(a[:, 0:3] - a[0, 0:3], axis=1))), "R": float(np.max(rot)),
            "w": float(np.max(np.linalg.norm(a[:, 10:13], axis=1)))}


def hover_start(height: float = 1.0) -> np.ndarray:
    x = np.zeros(13)
    x[2] = height
    x[6] = 1.0
    return x


def trimmed(u: np.ndarray, vehicle) -> np.ndarray:
    """The measured speeds, each rotor scaled so that the window's mean wrench is hover (thrust m g, no
    torque): open loop, without the controller that flew them, the vehicle then neither tumbles away nor
    falls in 2 s; each rotor's fluctuations keep their measured shape."""
    target = np.linalg.solve(vehicle.rotors.matrix, [vehicle.mass * 9.81, 0.0, 0.0, 0.0])  # mean u² per rotor
    return u * np.sqrt(target / np.mean(u**2, axis=0))


def hybrid_file(vehicle, folder, seed: int = 7, force: float = 0.01, torque: float = 1e-5,
                remainder: float = 0.0):
    """``folder/hybrid_vehicle.yaml`` and its ``residual.npz``, written as ``qr learn residual`` writes them
    (:func:`qr.residual.save_weights`, :func:`qr.residual.block`, :func:`qr.vehicle.save_vehicle`): ``vehicle``
    plus an untrained network (every input group, tanh, 17-12-6; seeded weights) whose output is about ``force``
    N and ``torque`` N m, and, if ``remainder`` > 0, a learned torque remainder of weights about that size."""
    from pathlib import Path

    from qr import residual as rs
    from qr import torque_remainder as tr
    from qr.vehicle import save_vehicle

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    inputs = ("v_b", "omega", "g_b", "u", "u2")
    scale = vehicle.hover_speed / 0.7  # rotor speeds near 0.7 of the scale in hover, as qr learn residual has them
    mean = np.r_[np.zeros(9), np.full(4, 0.7), np.full(4, 0.49)]
    spread = np.r_[np.full(3, 0.5), np.full(3, 2.0), np.full(3, 0.2), np.full(4, 0.03), np.full(4, 0.04)]
    net = rs.Residual(inputs, "tanh", (rng.normal(0, 0.6, (12, 17)), rng.normal(0, 0.6, (6, 12))),
                      (rng.normal(0, 0.2, 12), rng.normal(0, 0.2, 6)), mean, spread,
                      np.r_[np.full(3, force), np.full(3, torque)], scale)
    rs.save_weights(net, folder / "residual.npz")
    raw = vehicle.to_dict()
    raw["residual"] = rs.block(net, str((folder / "residual.npz").resolve()), "an untrained network (tests)",
                               rs.rms_size(net, np.zeros((1, 3)), np.zeros((1, 3)), np.array([[0.0, 0.0, -1.0]]),
                                           np.full((1, 4), vehicle.hover_speed), ["hover.csv"]))
    if remainder > 0:
        raw["torque_remainder"] = tr.block(rng.normal(0, remainder, (3, 11)), "a seeded remainder (tests)")
    save_vehicle(raw, folder / "hybrid_vehicle.yaml")
    return folder / "hybrid_vehicle.yaml"
