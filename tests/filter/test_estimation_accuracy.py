"""Errors against the noise-free truth of `qr synth` flights: the smoother beats the forward filter.

The flight comes from the `qr synth` command (mocap position and attitude
noise, rotor-speed noise, dropouts on), is read back with
``qr.flight.read_flight``, and each estimate is compared with
``truth.parquet``.  The error table is printed (run with ``-s``; the README
quotes it).
"""

import numpy as np
import pandas as pd
import pytest

from conftest import VEHICLES
from qr.estimation import estimate
from qr.flight import read_flight
from qr.frames import quat_multiply, rotation
from qr.vehicle import load_vehicle

GROUPS = {"v (m/s)": ["vx", "vy", "vz"], "a (m/s²)": ["ax", "ay", "az"], "ω (rad/s)": ["wx", "wy", "wz"],
          "α (rad/s²)": ["alx", "aly", "alz"], "u (rpm)": ["u1", "u2", "u3", "u4"],
          "u̇ (rpm/s)": ["ud1", "ud2", "ud3", "ud4"]}
CONFIGS = {"thesis forward": "thesis", "thesis smoother": "smoother", "auto forward": "auto_forward",
           "auto smoother": "auto"}


def attitude_error(states, truth):
    """Angle (rad) of q_true⁻¹ ⊗ q_est, sign-invariant."""
    q, qt = states[["qw", "qx", "qy", "qz"]].to_numpy(), truth[["qw", "qx", "qy", "qz"]].to_numpy()
    return np.linalg.norm(rotation(quat_multiply(qt * [1, -1, -1, -1], q)).as_rotvec(), axis=1)


def rms_errors(states, truth, edge_s=1.0):
    """RMS error per quantity, leaving out ``edge_s`` at both ends (start-up transients)."""
    t = truth["t"].to_numpy()
    inner = (t > t[0] + edge_s) & (t < t[-1] - edge_s)
    out = {name: float(np.sqrt(np.mean((states[c].to_numpy() - truth[c].to_numpy())[inner] ** 2)))
           for name, c in GROUPS.items()}
    out["θ (mrad)"] = 1e3 * float(np.sqrt(np.mean(attitude_error(states, truth)[inner] ** 2)))
    return out


def config(name):
    from qr.config import compose, to_dict

    if name == "auto_forward":
        return {**to_dict(compose(["filter=auto"]))["filter"], "smoother": False}
    return to_dict(compose([f"filter={name}"]))["filter"]


@pytest.fixture(scope="module")
def errors(tmp_path_factory):
    from qr.cli import main

    out = tmp_path_factory.mktemp("synth") / "s"
    status = main(["synth", "--vehicle", str(VEHICLES / "asctec_hummingbird.yaml"), "--duration", "60", "--rate", "100",
                   "--seed", "3", "--effect", "linear_drag:kx=0.3,ky=0.3,kz=0.1", "--out", str(out)])
    assert status == 0
    flight = read_flight(out / "flight.csv")
    truth = pd.read_parquet(out / "truth.parquet")
    vehicle = load_vehicle(out / "vehicle.yaml")
    table = {label: rms_errors(estimate(flight, vehicle, config(name))[0], truth) for label, name in CONFIGS.items()}
    frame = pd.DataFrame(table).T
    print("\nRMS error against the noise-free truth, qr synth 60 s at 100 Hz (hummingbird, seed 3, default noise):\n"
          + frame.to_markdown(floatfmt=".4g"))
    return table


@pytest.mark.parametrize("model", ["thesis", "auto"])
@pytest.mark.parametrize("quantity", ["v (m/s)", "a (m/s²)", "ω (rad/s)", "α (rad/s²)"])
def test_smoother_beats_forward_filter(errors, model, quantity):
    assert errors[f"{model} smoother"][quantity] < errors[f"{model} forward"][quantity]


@pytest.mark.parametrize("quantity", ["v (m/s)", "a (m/s²)", "ω (rad/s)", "α (rad/s²)", "θ (mrad)"])
def test_tuned_smoother_beats_the_thesis_tuning(errors, quantity):
    """filter=auto (likelihood-tuned noise) does better than the thesis's trial-and-error values."""
    assert errors["auto smoother"][quantity] < errors["thesis smoother"][quantity]


def test_eskf_keeps_a_unit_quaternion_through_10_minutes_of_tumbling_yaw(hummingbird):
    """600 s at 100 Hz spinning at 1.5 rad/s about z (~140 turns): unit norm, no drift of the attitude error."""
    from qr.sim.synth import SynthConfig, synthesize
    from qr.sim.trajectory import TrajectoryConfig

    flight, truth = synthesize(hummingbird, [], SynthConfig(duration=600.0, rate=100.0, seed=5,
                                                             trajectory=TrajectoryConfig(yaw_rate=1.5)))
    R = rotation(truth[["qw", "qx", "qy", "qz"]].to_numpy()).as_matrix()
    turns = np.ptp(np.unwrap(np.arctan2(R[:, 1, 0], R[:, 0, 0]))) / (2 * np.pi)
    assert turns > 100
    for cfg in ({}, {"smoother": True}):
        states, _ = estimate(flight, hummingbird, cfg)
        q = states[["qw", "qx", "qy", "qz"]].to_numpy()
        assert np.max(np.abs(np.linalg.norm(q, axis=1) - 1)) < 1e-12
        err = attitude_error(states, truth)
        first, last = err[100:6000].mean(), err[-6000:].mean()
        print(f"\ntumbling yaw, {turns:.0f} turns, smoother={bool(cfg)}: mean attitude error first minute "
              f"{1e3 * first:.2f} mrad, last minute {1e3 * last:.2f} mrad, max {1e3 * err[100:].max():.1f} mrad")
        assert last < 1.5 * first and err[100:].max() < 0.05  # no drift, no divergence (noise is 3 mrad)
        w_err = np.abs(states["wz"] - truth["wz"]).to_numpy()[100:]
        assert np.mean(w_err) < 0.05 * np.abs(truth["wz"]).mean()
