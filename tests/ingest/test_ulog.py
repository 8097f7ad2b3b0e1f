"""PX4 ULog: the frames (NED/FRD -> ENU/FLU), and two real PX4 logs read against pyulog's own CSV export.

The expected numbers come from ``ulog2csv`` (pyulog's command-line exporter, run here), not from the
adapter's code path: positions are the exporter's ``y, x, -z`` at the same stamps, commands the PWM
scaled by the log's own ``PWM_MIN``/``PWM_MAX``, gyro and accelerometer the exporter's FRD samples with
y and z negated, interpolated onto the pose stamps.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from conftest import ROOT, VEHICLES, run_cli
from qr.frames import from_ned_frd, frd_to_flu, quat_to_rot
from qr.ingest import detect_format, ulog

PX4 = Path(ROOT.parent / "shared" / "data" / "px4-ulog-samples")
needs_logs = pytest.mark.skipif(not (PX4 / "sample.ulg").exists(), reason="PX4 sample logs not present")


def _ned(roll=0.0, pitch=0.0, yaw=0.0):
    """PX4's attitude quaternion (FRD body -> NED world) from its Euler angles (z-y-x, as PX4 defines them)."""
    return Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_quat(scalar_first=True)[None, :]


def test_a_hover_facing_north_reads_as_level_with_the_nose_along_world_y():
    p, q = from_ned_frd(np.array([[1.0, 2.0, -3.0]]), _ned())  # 1 m north, 2 m east, 3 m up
    assert p[0] == pytest.approx([2.0, 1.0, 3.0])
    R = quat_to_rot(q[0])
    assert R[:, 0] == pytest.approx([0, 1, 0], abs=1e-12)  # body forward: north = ENU y
    assert R[:, 1] == pytest.approx([-1, 0, 0], abs=1e-12)  # body left: west
    assert R[:, 2] == pytest.approx([0, 0, 1], abs=1e-12)  # thrust axis up


def test_a_forward_pitch_tilts_the_thrust_towards_the_heading():
    """Nose down by 10 deg (PX4 pitch -10 deg) while facing east: the thrust axis leans east, the nose dips."""
    _, q = from_ned_frd(np.zeros((1, 3)), _ned(pitch=np.radians(-10), yaw=np.radians(90)))
    R = quat_to_rot(q[0])
    s, c = np.sin(np.radians(10)), np.cos(np.radians(10))
    assert R[:, 2] == pytest.approx([s, 0, c], abs=1e-12)  # thrust: east and up
    assert R[:, 0] == pytest.approx([c, 0, -s], abs=1e-12)  # nose: east, below the horizon
    # a body rate about FRD y (nose up) is a rate about FLU -y; a specific force along FRD -z is FLU +z
    assert frd_to_flu(np.array([[0.1, 0.2, 0.3]]))[0] == pytest.approx([0.1, -0.2, -0.3])


def _export(tmp_path, name, topics):
    subprocess.run([str(Path(sys.executable).parent / "ulog2csv"), "-m", ",".join(topics), "-o", str(tmp_path),
                    str(PX4 / name)], check=True, capture_output=True)
    stem = Path(name).stem
    return {t: pd.read_csv(tmp_path / f"{stem}_{t}_0.csv") for t in topics}


@needs_logs
@pytest.mark.parametrize("name, pwm", [("sample.ulg", (1075, 1950)), ("sample_log_small.ulg", (950, 2000))])
def test_a_real_px4_log_reads_in_qr_frames_and_units(tmp_path, name, pwm):
    df = ulog.read(PX4 / name, check=False)  # (neither log holds a flight: see the tests below)
    ref = _export(tmp_path, name, ["vehicle_local_position", "actuator_outputs", "sensor_combined"])
    lp, out, imu = ref["vehicle_local_position"], ref["actuator_outputs"], ref["sensor_combined"]
    stamps = lp["timestamp"].to_numpy()
    assert len(df) == len(np.unique(stamps))
    assert df["t"].iloc[0] == 0.0 and np.all(np.diff(df["t"]) > 0)
    assert df["t"].to_numpy() == pytest.approx((stamps - stamps[0]) * 1e-6)
    # a position PX4 marks invalid (no fix: xy_valid = 0, as on both logs) is a dropout, not 0 m
    xy_ok, z_ok = lp["xy_valid"].to_numpy() == 1, lp["z_valid"].to_numpy() == 1
    assert df["px"].to_numpy() == pytest.approx(np.where(xy_ok, lp["y"], np.nan), nan_ok=True)  # ENU x = NED east
    assert df["py"].to_numpy() == pytest.approx(np.where(xy_ok, lp["x"], np.nan), nan_ok=True)
    assert df["pz"].to_numpy() == pytest.approx(np.where(z_ok, -lp["z"], np.nan), nan_ok=True)

    def onto(ts, v):
        return np.interp(stamps, ts, v, left=np.nan, right=np.nan)

    lo, hi = pwm  # the log's PWM_MIN / PWM_MAX (ulog_params)
    for i in range(4):
        c = np.clip((out[f"output[{i}]"].to_numpy() - lo) / (hi - lo), 0, 1)
        assert df[f"u{i + 1}"].to_numpy() == pytest.approx(onto(out["timestamp"].to_numpy(), c), nan_ok=True)
    for j, (ax, sign) in enumerate(zip("xyz", (1, -1, -1))):
        g = onto(imu["timestamp"].to_numpy(), imu[f"gyro_rad[{j}]"].to_numpy())
        a = onto(imu["timestamp"].to_numpy(), imu[f"accelerometer_m_s2[{j}]"].to_numpy())
        assert df[f"g{ax}"].to_numpy() == pytest.approx(sign * g, nan_ok=True)
        assert df[f"a{ax}"].to_numpy() == pytest.approx(sign * a, nan_ok=True)
    # physics: level and at rest or hovering, the accelerometer reads +g along the FLU thrust axis, and
    # the attitude's thrust axis points up
    assert np.nanmedian(df["az"]) == pytest.approx(9.8, abs=0.4)
    q = df[["qw", "qx", "qy", "qz"]].dropna().to_numpy()
    assert np.median(quat_to_rot(q)[:, 2, 2]) > 0.95
    assert df.attrs["sources"]["pose"] == "vehicle_local_position + vehicle_attitude"
    assert df.attrs["rotor_input"] == "command"


@needs_logs
def test_a_ulog_is_recognised_by_its_content_not_its_name(tmp_path):
    renamed = tmp_path / "flight.csv"
    renamed.write_bytes((PX4 / "sample_log_small.ulg").read_bytes())
    assert detect_format(renamed) == "ulog"


def test_qr_ingest_of_a_px4_log_with_commands_only_says_what_is_missing(tmp_path, capsys):
    """A flight logged with motor commands, not ESC rpm (as most PX4 logs: both shared samples too), and a
    vehicle file without a command map: one line naming the log, the problem and the fix."""
    from ulog_writer import write_ulog

    t = np.arange(0, 5, 0.01)
    p = np.column_stack([np.sin(t), np.cos(t), 1 + 0 * t])
    q = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1))
    write_ulog(tmp_path / "f.ulg", t, p, q, np.full((len(t), 4), 0.5))
    out = tmp_path / "flight.csv"
    status, _, err = run_cli(["ingest", tmp_path / "f.ulg", "--vehicle", VEHICLES / "asctec_hummingbird.yaml",
                              "--out", out], capsys)
    assert status == 2
    (line,) = err.strip().splitlines()
    assert str(tmp_path / "f.ulg") in line and "motor commands (actuator_motors" in line
    assert "no command -> thrust map; fix: add rotor_input: command and command_map" in line
    assert "or log ESC telemetry (PX4: esc_status)" in line
    assert not out.exists()


def test_a_px4_log_whose_stamps_go_back_is_refused_as_damaged(tmp_path):
    """One pose stamp corrupted far ahead (a flipped bit): the next goes back; refused, never reordered."""
    from ulog_writer import write_ulog

    from qr.errors import QrInputError

    t = np.arange(0, 5, 0.01)
    t_log = t.copy()
    t_log[200] = 300.0
    p = np.column_stack([np.sin(t), np.cos(t), 1 + 0 * t])
    q = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1))
    write_ulog(tmp_path / "f.ulg", t_log, p, q, np.full((len(t), 4), 0.5), rpm=np.full((len(t), 4), 12000))
    with pytest.raises(QrInputError, match=r"timestamps go back at sample 201 \(from 301 s to 3.01 s\)"):
        ulog.read(tmp_path / "f.ulg", check=False)
    t_log[200] = t[200]  # the same log intact reads
    write_ulog(tmp_path / "g.ulg", t_log, p, q, np.full((len(t), 4), 0.5), rpm=np.full((len(t), 4), 12000))
    assert len(ulog.read(tmp_path / "g.ulg", check=False)) == len(t)


@needs_logs
@pytest.mark.parametrize("name, problem", [
    ("sample.ulg", "the vehicle was never armed in this log"),  # vehicle_status.arming_state 0 throughout
    ("sample_log_small.ulg", "no valid position in the whole log"),  # armed, but xy_valid = 0 throughout
])
def test_a_px4_log_that_holds_no_flight_is_refused_in_one_line(tmp_path, capsys, name, problem):
    out = tmp_path / "flight.csv"
    vehicle = tmp_path / "px4.yaml"
    vehicle.write_text((VEHICLES / "asctec_hummingbird.yaml").read_text()
                       + "rotor_input: command\ncommand_map: {a: 0.0, b: 1.0, k: 3.0}\n")
    status, _, err = run_cli(["ingest", PX4 / name, "--vehicle", vehicle, "--out", out], capsys)
    assert status == 2
    (line,) = err.strip().splitlines()
    assert str(PX4 / name) in line and problem in line and "fix: " in line
    assert not out.exists()


@pytest.mark.slow
def test_a_synthetic_flight_written_as_a_px4_ulog_with_esc_rpm_diagnoses_as_from_its_csv(tmp_path, capsys):
    """NED/FRD float32 pose, integer ESC rpm (``esc_status``): the same effects as from the CSV, the drag
    within half a standard error."""
    import json

    from ulog_writer import write_ulog

    hb = VEHICLES / "asctec_hummingbird.yaml"
    assert run_cli(["synth", "--vehicle", hb, "--effect", "linear_drag:kx=0.3,ky=0.3,kz=0.15", "--duration", "60",
                    "--seed", "8", "--out", tmp_path / "synth"], capsys)[0] == 0
    fl = pd.read_csv(tmp_path / "synth" / "flight.csv")
    u = fl[["u1", "u2", "u3", "u4"]].to_numpy()
    write_ulog(tmp_path / "f.ulg", fl["t"].to_numpy(), fl[["px", "py", "pz"]].to_numpy(),
               fl[["qw", "qx", "qy", "qz"]].to_numpy(), np.full_like(u, 0.5), rpm=u)
    status, _, err = run_cli(["ingest", tmp_path / "f.ulg", "--vehicle", hb, "--out", tmp_path / "f.parquet"], capsys)
    assert status == 0, err
    docs = []
    for src, out in ((tmp_path / "synth" / "flight.csv", "d_csv"), (tmp_path / "f.parquet", "d_ulog")):
        status, _, err = run_cli(["diagnose", src, "--vehicle", hb, "--out", tmp_path / out], capsys)
        assert status == 0, err
        docs.append({e["name"]: e for e in json.loads((tmp_path / out / "diagnosis.json").read_text())["effects"]})
    assert list(docs[0]) == list(docs[1]) and "linear_drag" in docs[0]
    csv, px4 = docs[0]["linear_drag"], docs[1]["linear_drag"]
    for k, v in csv["parameters"].items():
        assert px4["parameters"][k] == pytest.approx(v, abs=0.5 * csv["stderr"][k])
