"""ROS 1 bags, ROS 2 bags (sqlite3 and MCAP): a flight written with ``rosbags``' own writers reads back as
the same canonical flight, through ``qr ingest`` as a user types it, and diagnoses as from the CSV."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from conftest import VEHICLES, run_cli, small_flight
from qr.ingest import read_log
from qr.vehicle import load_vehicle
from rosbag_writer import write_bag

HB = VEHICLES / "asctec_hummingbird.yaml"  # rotor speeds in rpm; bags carry rad/s
RAD_S = 2 * math.pi / 60


def _flight():
    fl = small_flight(300, seed=2)
    rng = np.random.default_rng(2)
    for c in ("gx", "gy", "gz"):
        fl[c] = rng.normal(0, 0.1, len(fl))
    fl["ax"], fl["ay"], fl["az"] = 0.1, -0.2, 9.81
    return fl


def _bag(tmp_path, fl, kind, **kw):
    return write_bag(fl, tmp_path / ("flight.bag" if kind == "ros1" else f"bag_{kind}"), kind, RAD_S, **kw)


@pytest.mark.parametrize("kind", ["sqlite3", "mcap", "ros1"])
def test_a_bag_reads_back_as_the_flight_it_was_written_from(tmp_path, kind):
    fl = _flight()
    df = read_log(_bag(tmp_path, fl, kind), load_vehicle(HB))
    assert df["t"].to_numpy() == pytest.approx(fl["t"].to_numpy(), abs=1e-9)  # header stamps, in ns
    for c in ("px", "py", "pz", "qw", "qx", "qy", "qz", "gx", "gy", "gz", "ax", "ay", "az"):
        assert df[c].to_numpy() == pytest.approx(fl[c].to_numpy(), rel=1e-12, abs=1e-12), c
    for c in ("u1", "u2", "u3", "u4"):  # rad/s in the bag, the vehicle's rpm in the flight
        assert df[c].to_numpy() == pytest.approx(fl[c].to_numpy(), rel=1e-12), c


def test_odometry_is_a_pose_too(tmp_path):
    fl = _flight()
    df = read_log(_bag(tmp_path, fl, "sqlite3", odometry=True), load_vehicle(HB))
    assert df["pz"].to_numpy() == pytest.approx(fl["pz"].to_numpy())


def test_qr_ingest_takes_a_ros2_bag_folder_as_typed(tmp_path, capsys):
    bag = _bag(tmp_path, _flight(), "mcap")
    status, out, err = run_cli(["ingest", bag, "--vehicle", HB, "--out", tmp_path / "flight.csv"], capsys)
    assert status == 0, err
    assert len(pd.read_csv(tmp_path / "flight.csv")) == 300


def test_several_pose_topics_ask_for_one_and_topic_chooses(tmp_path, capsys):
    bag = _bag(tmp_path, _flight(), "sqlite3", extra_pose_topic="/vicon/quad")
    status, _, err = run_cli(["ingest", bag, "--vehicle", HB, "--out", tmp_path / "a.csv"], capsys)
    (line,) = err.strip().splitlines()
    assert status == 2 and "several pose topics (/mocap/pose, /vicon/quad)" in line
    assert "fix: choose one with --topic pose=/name" in line
    status, _, err = run_cli(["ingest", bag, "--vehicle", HB, "--out", tmp_path / "b.csv", "--topic",
                              "pose=/vicon/quad"], capsys)
    assert status == 0, err


@pytest.mark.parametrize("case, phrases", [
    ("no_rotors", ["no rotors topic (mav_msgs/Actuators", "the bag has: /imu (sensor_msgs/msg/Imu), "
                   "/mocap/pose (geometry_msgs/msg/PoseStamped)", "--topic rotors=/name"]),
    ("storage_file", ["one storage file of a ROS 2 bag", "the one holding metadata.yaml"]),
    ("bad_topic", ["--topic pose=/nope: no such topic"]),
    ("topic_for_csv", ["--topic is for ROS bags"]),
])
def test_a_bag_without_what_qr_needs_is_one_line(tmp_path, capsys, case, phrases):
    fl = _flight()
    extra = []
    if case == "no_rotors":
        src = _bag(tmp_path, fl, "sqlite3", rotors=False)
    elif case == "storage_file":
        src = next(_bag(tmp_path, fl, "mcap").glob("*.mcap"))
    elif case == "bad_topic":
        src, extra = _bag(tmp_path, fl, "sqlite3"), ["--topic", "pose=/nope"]
    else:
        src = tmp_path / "flight.csv"
        fl.to_csv(src, index=False)
        extra = ["--topic", "pose=/x"]
    out = tmp_path / "out.csv"
    status, _, err = run_cli(["ingest", src, "--vehicle", HB, "--out", out, *extra], capsys)
    (line,) = err.strip().splitlines()
    assert status == 2 and line.startswith("qr: error: ") and "fix:" in line
    for p in phrases:
        assert p in line, (p, line)
    assert not out.exists()


def test_a_synthetic_flight_from_a_ros2_bag_diagnoses_as_from_its_csv(tmp_path, capsys):
    """The hidden effect is found with the same parameters (to a tenth of their standard error): the
    bag's rows are the CSV's, to the ns stamps and the rpm -> rad/s -> rpm round trip."""
    status, _, err = run_cli(["synth", "--vehicle", HB, "--effect", "linear_drag:kx=0.3,ky=0.3,kz=0.15",
                              "--duration", "60", "--seed", "4", "--out", tmp_path / "synth"], capsys)
    assert status == 0, err
    fl = pd.read_csv(tmp_path / "synth" / "flight.csv")
    bag = _bag(tmp_path, fl, "sqlite3")
    assert run_cli(["ingest", bag, "--vehicle", tmp_path / "synth" / "vehicle.yaml", "--out",
                    tmp_path / "from_bag.parquet"], capsys)[0] == 0
    docs = []
    for src, out in ((tmp_path / "synth" / "flight.csv", "d_csv"), (tmp_path / "from_bag.parquet", "d_bag")):
        status, _, err = run_cli(["diagnose", src, "--vehicle", tmp_path / "synth" / "vehicle.yaml", "--out",
                                  tmp_path / out], capsys)
        assert status == 0, err
        docs.append(json.loads((tmp_path / out / "diagnosis.json").read_text()))
    names = [[e["name"] for e in d["effects"]] for d in docs]
    assert names[0] == names[1] and "linear_drag" in names[0]
    for a, b in zip(docs[0]["effects"], docs[1]["effects"]):
        for k in a["parameters"]:  # ns stamps move the tuning search (Brent, 1e-3 in log f) a little
            assert abs(b["parameters"][k] - a["parameters"][k]) < 0.1 * a["stderr"][k], (k, a, b)
    kx = next(e for e in docs[1]["effects"] if e["name"] == "linear_drag")["parameters"]["kx"]
    assert kx == pytest.approx(0.3, rel=0.1)
