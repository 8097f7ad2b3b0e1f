"""The accelerometer as an independent check of the force label (qr.diagnose.accelerometer).

A synthetic flight with drag gets accelerometer columns computed from the true motion (specific force
Rᵀ(a − g), body frame, plus 0.05 m/s² noise).  Physical expectations: the two labels share the drag
(slow correlation near 1) and differ by no constant; tilting the motion-capture frame 1° against
gravity (positions and attitudes rotated about world x, rotor speeds and accelerometer untouched)
adds to the motion-capture label a constant m g sin 1° in body x/y (the yaw stays put in these
flights), which the check reads back as a 1° tilt.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import VEHICLES
from qr.stages.diagnose import run_diagnosis
from qr.frames import quat_to_rot
from qr.sim.synth import SynthConfig, simulate_truth, add_noise, NoiseConfig

G = 9.81


@pytest.fixture(scope="module")
def flight():
    from qr.vehicle import load_vehicle

    v = load_vehicle(VEHICLES / "asctec_hummingbird.yaml")
    eff = [{"name": "linear_drag", "parameters": {"kx": 0.3, "ky": 0.3, "kz": 0.15}}]
    truth = simulate_truth(v, eff, SynthConfig(duration=30, rate=100, seed=5))
    rng = np.random.default_rng(1)
    df = add_noise(truth, v, NoiseConfig(dropout=0.0), rng)
    R = quat_to_rot(truth[["qw", "qx", "qy", "qz"]].to_numpy())
    a_w = truth[["ax", "ay", "az"]].to_numpy() + [0.0, 0.0, G]
    df[["ax", "ay", "az"]] = np.einsum("nji,nj->ni", R, a_w) + rng.normal(0, 0.05, (len(df), 3))
    return v, df


def _diagnose(tmp_path, df, name):
    path = tmp_path / f"{name}.csv"
    df.to_csv(path, index=False)
    doc = run_diagnosis([path], VEHICLES / "asctec_hummingbird.yaml", tmp_path / name, track=False,
                        figures=False, log=lambda m: None)
    return doc["accelerometer_check"], (tmp_path / name / "report.md").read_text()


def test_the_labels_agree_on_the_physics_and_a_tilted_mocap_frame_shows(flight, tmp_path):
    v, df = flight
    check, report = _diagnose(tmp_path, df, "level")
    assert check["samples"] > 2000
    assert np.hypot(*check["difference"][:2]) < 0.1 * v.mass * G * np.sin(np.radians(1.0))
    assert check["tilt_deg"] < 0.1
    assert min(check["correlation_slow"][:2]) > 0.95  # the drag, seen by both sensors
    assert "The force label against the accelerometer" in report

    tilt = Rotation.from_euler("x", 1.0, degrees=True)
    tilted = df.copy()
    tilted[["px", "py", "pz"]] = tilt.apply(df[["px", "py", "pz"]].to_numpy())
    q = df[["qw", "qx", "qy", "qz"]].to_numpy()
    tilted[["qx", "qy", "qz", "qw"]] = (tilt * Rotation.from_quat(q[:, [1, 2, 3, 0]])).as_quat()
    check, _ = _diagnose(tmp_path, tilted, "tilted")
    expected = v.mass * G * np.sin(np.radians(1.0))
    assert np.hypot(*check["difference"][:2]) == pytest.approx(expected, rel=0.15)
    assert check["tilt_deg"] == pytest.approx(1.0, abs=0.15)


def test_no_accelerometer_no_check(flight, tmp_path):
    _, df = flight
    check, report = _diagnose(tmp_path, df.drop(columns=["ax", "ay", "az"]), "none")
    assert check is None and "The force label against the accelerometer" not in report
