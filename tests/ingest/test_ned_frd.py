"""A CSV in PX4's frames (NED world, FRD body): refused by ``qr diagnose`` with the command that converts
it, converted by that command (``qr ingest --frame ned-frd``) back to the flight it was made from, and
diagnosed the same.

The NED/FRD log is written here from the frames' definitions (north = ENU y, east = ENU x, down = −z;
forward-right-down body; scipy's rotations), independently of ``qr.frames``.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from conftest import VEHICLES, run_cli
from qr.flight import read_flight, to_spec_frames
from qr.sim.synth import SynthConfig, write_synth
from qr.vehicle import load_vehicle

CANDIDATES = "diagnose.candidates=[linear_drag,wind_force,mass_error,thrust_gain]"
ENU_NED = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
FLU_FRD = np.diag([1.0, -1, -1])


def _with_sensors(d):
    """The synthetic flight with the velocity, gyro and accelerometer of its truth (spec frames)."""
    df = pd.read_csv(d / "flight.csv")
    truth = pd.read_parquet(d / "truth.parquet")
    R = Rotation.from_quat(truth[["qw", "qx", "qy", "qz"]].to_numpy(), scalar_first=True).as_matrix()
    f_world = truth[["ax", "ay", "az"]].to_numpy() + [0, 0, 9.81]
    rng = np.random.default_rng(0)
    df[["vx", "vy", "vz"]] = truth[["vx", "vy", "vz"]].to_numpy()
    df[["gx", "gy", "gz"]] = truth[["wx", "wy", "wz"]].to_numpy() + rng.normal(0, 0.01, (len(df), 3))
    df[["ax", "ay", "az"]] = np.einsum("nji,nj->ni", R, f_world) + rng.normal(0, 0.05, (len(df), 3))
    return df


def _as_px4(df):
    out = df.copy()
    for cols in (["px", "py", "pz"], ["vx", "vy", "vz"]):
        out[cols] = df[cols].to_numpy() @ ENU_NED.T
    q = df[["qw", "qx", "qy", "qz"]].to_numpy()
    ok = np.isfinite(q).all(axis=1)
    R = Rotation.from_quat(q[ok], scalar_first=True).as_matrix()
    qn = np.full_like(q, np.nan)
    qn[ok] = Rotation.from_matrix(ENU_NED @ R @ FLU_FRD).as_quat(scalar_first=True)
    out[["qw", "qx", "qy", "qz"]] = qn
    for c in ("gy", "gz", "ay", "az"):
        out[c] = -df[c]
    return out


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    d = tmp_path_factory.mktemp("ned")
    write_synth(d / "s", load_vehicle(VEHICLES / "asctec_hummingbird.yaml"),
                [{"name": "linear_drag", "parameters": {"kx": 0.3, "ky": 0.3, "kz": 0.1}}],
                SynthConfig(duration=20, seed=1))
    enu = _with_sensors(d / "s")
    enu.to_csv(d / "enu.csv", index=False)
    _as_px4(enu).to_csv(d / "px4.csv", index=False)
    return d


def test_a_px4_csv_is_refused_with_the_command_that_converts_it(flights, tmp_path, capsys):
    vehicle = flights / "s" / "vehicle.yaml"
    status, _, err = run_cli(["diagnose", flights / "px4.csv", "--vehicle", vehicle, "--out", tmp_path / "d"], capsys)
    assert status == 2, err
    (line,) = err.strip().splitlines()
    assert "NED world with an FRD body" in line, line
    assert f"qr ingest {flights / 'px4.csv'} --vehicle {vehicle} --frame ned-frd --out FLIGHT.csv" in line, line
    assert not (tmp_path / "d").exists()
    # qr ingest without --frame refuses it the same way, naming the same command
    status, _, err = run_cli(["ingest", flights / "px4.csv", "--vehicle", vehicle, "--out", tmp_path / "x.csv"],
                             capsys)
    assert status == 2 and "--frame ned-frd" in err and "--skip-check thrust_axis" in err, err
    assert not (tmp_path / "x.csv").exists()


def test_qr_ingest_frame_ned_frd_gives_back_the_flight_and_its_diagnosis(flights, tmp_path, capsys):
    vehicle = flights / "s" / "vehicle.yaml"
    out = tmp_path / "flight.csv"
    status, _, err = run_cli(["ingest", flights / "px4.csv", "--vehicle", vehicle, "--frame", "ned-frd",
                              "--out", out], capsys)
    assert status == 0, err
    back, orig = read_flight(out), read_flight(flights / "enu.csv")
    assert list(back.columns) == list(orig.columns)
    exact = ["t", "px", "py", "pz", "vx", "vy", "vz", "gx", "gy", "gz", "ax", "ay", "az", "u1", "u2", "u3", "u4"]
    pd.testing.assert_frame_equal(back[exact], orig[exact], check_exact=True)  # swaps and sign changes: exact
    q, q0 = back[["qw", "qx", "qy", "qz"]].to_numpy(), orig[["qw", "qx", "qy", "qz"]].to_numpy()
    ok = np.isfinite(q0).all(axis=1)
    assert (np.isfinite(q).all(axis=1) == ok).all()  # the dropouts stay where they were
    q, q0 = q[ok], q0[ok]
    q *= np.sign(np.sum(q * q0, axis=1))[:, None]  # q and -q: one attitude
    np.testing.assert_allclose(q, q0, rtol=0, atol=4e-16)
    docs = []
    for f, d in ((flights / "enu.csv", "d0"), (out, "d1")):
        status, _, err = run_cli(["diagnose", f, "--vehicle", vehicle, "--out", tmp_path / d, CANDIDATES], capsys)
        assert status == 0, err
        docs.append(json.loads((tmp_path / d / "diagnosis.json").read_text()))
    a, b = docs
    assert [e["name"] for e in a["effects"]] == [e["name"] for e in b["effects"]] == ["linear_drag"]
    for ea, eb in zip(a["effects"], b["effects"]):
        assert eb["parameters"] == pytest.approx(ea["parameters"], rel=1e-9)
    assert a["verdict"] == b["verdict"]


def test_a_ned_velocity_needs_its_three_components():
    df = pd.DataFrame({"t": [0.0, 0.01], "px": 1.0, "py": 2.0, "pz": -3.0, "qw": 1.0, "qx": 0.0, "qy": 0.0,
                       "qz": 0.0, "vx": 1.0, "vy": 2.0})
    with pytest.raises(Exception, match="vx, vy but not vz"):
        to_spec_frames(df, "ned-frd")
    enu = to_spec_frames(df.drop(columns=["vx", "vy"]), "ned-frd")
    assert enu[["px", "py", "pz"]].iloc[0].tolist() == [2.0, 1.0, 3.0]
    # the identity attitude in NED/FRD, level and facing north: in ENU/FLU body x (forward) is world y (north),
    # body y (left) world -x (west), body z up: a yaw of +90 degrees, q = [cos 45°, 0, 0, sin 45°]
    np.testing.assert_allclose(np.abs(enu[["qw", "qx", "qy", "qz"]].iloc[0]), [2**-0.5, 0, 0, 2**-0.5], atol=1e-15)


def test_a_ulog_needs_no_frame(tmp_path, capsys):
    log = tmp_path / "a.ulg"
    log.write_bytes(b"ULog\x01\x12\x35\x01" + bytes(64))
    status, _, err = run_cli(["ingest", log, "--vehicle", VEHICLES / "asctec_hummingbird.yaml", "--frame", "ned-frd",
                              "--out", tmp_path / "f.csv"], capsys)
    assert status == 2 and "--frame ned-frd is for CSV" in err and "leave --frame out" in err, err


def test_the_command_line_knows_the_frames_qr_converts():
    from qr.cli import _parser
    from qr.flight import FRAMES

    ingest = next(a for a in _parser()._subparsers._group_actions[0].choices["ingest"]._actions if a.dest == "frame")
    assert list(ingest.choices) == list(FRAMES) and ingest.default == "enu-flu"
