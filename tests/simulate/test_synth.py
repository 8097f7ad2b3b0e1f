import json

import numpy as np
import pandas as pd
import pytest
import yaml

from conftest import VEHICLES, run_cli
from decisions import needs_two_kernels
from qr.sim.synth import SynthConfig
from qr.frames import quat_to_rot
from qr.vehicle import load_vehicle

HB = VEHICLES / "asctec_hummingbird.yaml"


@pytest.fixture(scope="module")
def synth_dir(tmp_path_factory):
    from qr.cli import main

    out = tmp_path_factory.mktemp("synth") / "s1"
    status = main(["synth", "--vehicle", str(HB), "--duration", "60", "--rate", "100", "--seed", "1",
                   "--effect", "linear_drag:kx=0.3,ky=0.3,kz=0.1", "--effect", "cg_offset:rx=0.01,ry=0",
                   "--out", str(out)])
    assert status == 0
    return out


def test_writes_flight_nominal_vehicle_and_truth(synth_dir, hummingbird):
    written = {"flight.csv", "vehicle.yaml", "truth.json", "truth.parquet"}
    assert {p.name for p in synth_dir.iterdir()} == written | {".qr-output.json"}
    assert set(json.loads((synth_dir / ".qr-output.json").read_text())["files"]) == written
    flight = pd.read_csv(synth_dir / "flight.csv")
    assert len(flight) == 6001 and np.diff(flight["t"]).min() > 0
    v = load_vehicle(synth_dir / "vehicle.yaml")
    assert v.mass == hummingbird.mass and not v.effects  # the NOMINAL vehicle
    np.testing.assert_allclose(v.rotors.matrix, hummingbird.rotors.matrix)
    truth = json.loads((synth_dir / "truth.json").read_text())
    assert [e["name"] for e in truth["effects"]] == ["linear_drag", "cg_offset"]
    assert truth["effects"][0]["parameters"] == {"kx": 0.3, "ky": 0.3, "kz": 0.1}
    assert truth["effects"][1]["parameters"] == {"rx": 0.01, "ry": 0.0}


def test_trajectory_excites_all_axes(synth_dir):
    truth = pd.read_parquet(synth_dir / "truth.parquet")
    speed = np.hypot(truth["vx"], truth["vy"]).max()
    assert 2.0 < speed < 2.8
    R = quat_to_rot(truth[["qw", "qx", "qy", "qz"]].to_numpy())
    tilt = np.degrees(np.arccos(np.clip(R[:, 2, 2], -1, 1))).max()
    assert 18 < tilt < 35
    yaw = np.unwrap(np.arctan2(R[:, 1, 0], R[:, 0, 0]))
    assert np.ptp(yaw) > np.radians(30)
    assert truth["vz"].abs().max() > 0.2


def test_noise_and_dropouts_match_the_settings(synth_dir):
    flight = pd.read_csv(synth_dir / "flight.csv")
    truth = pd.read_parquet(synth_dir / "truth.parquet")
    dp = (flight[["px", "py", "pz"]] - truth[["px", "py", "pz"]]).to_numpy()
    ok = np.isfinite(dp).all(axis=1)
    assert np.nanstd(dp[ok]) == pytest.approx(0.0005, rel=0.05)
    assert (~ok).mean() == pytest.approx(0.005, abs=0.002)
    du = (flight[["u1", "u2", "u3", "u4"]] - truth[["u1", "u2", "u3", "u4"]]).to_numpy()
    hover = np.sqrt(0.7 * 9.81 / (4 * 4.9782e-8))
    assert du.std() == pytest.approx(0.005 * hover, rel=0.05)


def test_same_seed_same_flight(tmp_path, capsys):
    for name in ("a", "b"):
        status, _, err = run_cli(["synth", "--vehicle", HB, "--duration", "10", "--seed", "5",
                                  "--effect", "wind_force:fx=0.3,fy=0,fz=0", "--out", tmp_path / name], capsys)
        assert status == 0, err
    assert (tmp_path / "a" / "flight.csv").read_bytes() == (tmp_path / "b" / "flight.csv").read_bytes()
    status, _, _ = run_cli(["synth", "--vehicle", HB, "--duration", "10", "--seed", "6", "--out", tmp_path / "c"],
                           capsys)
    assert (tmp_path / "a" / "flight.csv").read_bytes() != (tmp_path / "c" / "flight.csv").read_bytes()


def test_low_passes_and_yaw_spin(tmp_path, capsys):
    status, _, err = run_cli(["synth", "--vehicle", HB, "--duration", "30", "--low-passes", "--yaw-rate", "1.0",
                              "--noise-free", "--out", tmp_path / "g"], capsys)
    assert status == 0, err
    truth = pd.read_parquet(tmp_path / "g" / "truth.parquet")
    assert truth["pz"].min() < 0.2
    R = quat_to_rot(truth[["qw", "qx", "qy", "qz"]].to_numpy())
    yaw = np.unwrap(np.arctan2(R[:, 1, 0], R[:, 0, 0]))
    assert yaw[-1] - yaw[0] > 20  # about 27 rad of spin in 30 s, less the fade-in


def test_extended_vehicle_effects_are_simulated(tmp_path, capsys):
    raw = yaml.safe_load(HB.read_text())
    raw["effects"] = [{"name": "body_force_bias", "parameters": {"bx": 0, "by": 0, "bz": 0.5}}]
    ext = tmp_path / "extended.yaml"
    ext.write_text(yaml.safe_dump(raw))
    status, _, err = run_cli(["synth", "--vehicle", ext, "--duration", "5", "--out", tmp_path / "e"], capsys)
    assert status == 0, err
    truth = json.loads((tmp_path / "e" / "truth.json").read_text())
    assert truth["effects"][0]["name"] == "body_force_bias"
    assert not load_vehicle(tmp_path / "e" / "vehicle.yaml").effects


@needs_two_kernels
def test_a_synthetic_flight_is_the_same_file_under_another_blas_kernel_and_thread_count(tmp_path):
    """The plant, the controller's matrix products, its rotor-map inverse and LQR gain round the same on
    every processor (no BLAS in them): the written flight is byte-identical.  A 40 ms delay on the
    Crazyflie, the kind of flight whose closed loop amplifies the last bits most."""
    import subprocess
    import sys

    from decisions import other_machine

    args = ["synth", "--vehicle", str(VEHICLES / "crazyflie21_brushless.yaml"), "--duration", "30", "--seed", "4",
            "--effect", "actuator_delay:delay_s=0.04", "--effect", "wind_force:fx=0.01,fy=-0.02,fz=0.005"]
    here = subprocess.run([sys.executable, "-m", "qr.cli", *args, "--out", str(tmp_path / "a")], capture_output=True)
    there = subprocess.run([sys.executable, "-m", "qr.cli", *args, "--out", str(tmp_path / "b")],
                           env=other_machine(0), capture_output=True)
    assert here.returncode == 0 and there.returncode == 0, (here.stderr, there.stderr)
    assert (tmp_path / "a" / "flight.csv").read_bytes() == (tmp_path / "b" / "flight.csv").read_bytes()


def test_a_flight_the_controller_loses_is_refused(monkeypatch):
    """A vehicle whose controller cannot fly its hidden effects (a rotor delay of 60 ms on the Crazyflie's
    fast attitude loop, with the loop kept at the default bandwidth) is no flight a pilot would log."""
    import qr.sim.control as control
    from qr.errors import QrInputError
    from qr.sim.synth import simulate_truth

    vehicle = load_vehicle(VEHICLES / "crazyflie21_brushless.yaml")
    delay = [{"name": "actuator_delay", "parameters": {"delay_s": 0.06}}]
    simulate_truth(vehicle, delay, SynthConfig(duration=20, seed=1))  # the loop slowed for the lag: it flies
    monkeypatch.setattr(control, "LAG_AT_DEFAULT", 1.0)  # never slowed
    with pytest.raises(QrInputError, match="the controller lost the vehicle"):
        simulate_truth(vehicle, delay, SynthConfig(duration=20, seed=1))
