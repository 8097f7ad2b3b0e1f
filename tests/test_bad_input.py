"""Every unusable input: exit 2, one line naming the file, the problem and the fix, nothing written."""

import shutil

import numpy as np
import pandas as pd
import pytest

from conftest import DATA, VEHICLES, run_cli
from test_flight_io import _flight

HB = VEHICLES / "asctec_hummingbird.yaml"


def assert_rejected(capsys, tmp_path, args, *phrases):
    out = tmp_path / "out" / "flight.csv"
    out.parent.mkdir(exist_ok=True)  # the folder an output goes in must exist (tests/test_output_safety.py)
    status, _, err = run_cli([*args, "--out", out], capsys)
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("qr: error: ") and "fix:" in lines[0]
    for p in phrases:
        assert p in lines[0], (p, lines[0])
    assert not out.exists()
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
    return lines[0]


def _csv(tmp_path, df, name="bad.csv"):
    p = tmp_path / name
    df.to_csv(p, index=False)
    return p


@pytest.mark.parametrize("case, phrases", [
    ("missing", ["missing column(s) 'pz'"]),
    ("misspelled", ["'qw' (found 'q_w': misspelled?)"]),
    ("non_numeric", ["non-numeric value 'abc' in column 'px' at line 7"]),
    ("not_increasing", ["not strictly increasing"]),
    ("duplicated", ["duplicated time stamp"]),
    ("quat_norm", ["quaternion norm 2.000", "far from 1"]),
    ("negative_rotor", ["negative rotor speed", "'u2'"]),
    ("rad_s_for_rpm", ["unit or coefficient error", "look like rad_s"]),
    ("header_only", ["no samples"]),
])
def test_bad_flight_csv(case, phrases, tmp_path, capsys):
    df = _flight()
    if case == "missing":
        df = df.drop(columns="pz")
    elif case == "misspelled":
        df = df.rename(columns={"qw": "q_w"})
    elif case == "non_numeric":
        df["px"] = df["px"].astype(object)
        df.loc[5, "px"] = "abc"
    elif case == "not_increasing":
        df.loc[40, "t"] = df.loc[38, "t"]
    elif case == "duplicated":
        df.loc[40, "t"] = df.loc[39, "t"]
    elif case == "quat_norm":
        df.loc[10, ["qw", "qx", "qy", "qz"]] = [2.0, 0, 0, 0]
    elif case == "negative_rotor":
        df.loc[3, "u2"] = -100.0
    elif case == "rad_s_for_rpm":
        df[["u1", "u2", "u3", "u4"]] *= 2 * np.pi / 60
    elif case == "header_only":
        df = df.iloc[:0]
    path = _csv(tmp_path, df)
    line = assert_rejected(capsys, tmp_path, ["ingest", path, "--vehicle", HB], *phrases)
    assert str(path) in line


def test_empty_file(tmp_path, capsys):
    path = tmp_path / "empty.csv"
    path.write_text("")
    assert_rejected(capsys, tmp_path, ["ingest", path, "--vehicle", HB], "empty", str(path))


@pytest.mark.parametrize("damage", ["truncated", "corrupted"])
def test_damaged_binary_log(damage, tmp_path, capsys):
    src = DATA / "brushless_flights" / "data" / "eckart00"
    data = bytearray(src.read_bytes())
    if damage == "truncated":
        data = data[: len(data) // 2]
    else:
        data[len(data) // 3] ^= 0xFF
    path = tmp_path / "eckart00"
    path.write_bytes(bytes(data))
    assert_rejected(capsys, tmp_path, ["ingest", path, "--vehicle", VEHICLES / "crazyflie21_brushless.yaml"],
                     "CRC32 check failed", "truncated or corrupted", str(path))


@pytest.mark.parametrize("edit, phrases", [
    ({"drop": "thrust_coeff"}, ["lacks key(s) 'thrust_coeff'"]),
    ({"rename": ("torque_coeff", "torque_coef")}, ["'torque_coeff' (found 'torque_coef')"]),
    ({"set": ("mass", -0.7)}, ["'mass' is -0.7, not a positive number"]),
    ({"set": ("thrust_coeff", "big")}, ["'thrust_coeff' is 'big', not a number"]),
    ({"set": ("inertia", [0.007, 0.007])}, ["'inertia'"]),
    ({"set": ("rotor_speed_unit", "rps")}, ["rotor_speed_unit is 'rps'"]),
])
def test_bad_vehicle(edit, phrases, tmp_path, capsys):
    import yaml

    raw = yaml.safe_load(HB.read_text())
    if "drop" in edit:
        raw.pop(edit["drop"])
    if "rename" in edit:
        a, b = edit["rename"]
        raw[b] = raw.pop(a)
    if "set" in edit:
        raw[edit["set"][0]] = edit["set"][1]
    vpath = tmp_path / "vehicle.yaml"
    vpath.write_text(yaml.safe_dump(raw))
    flight = _csv(tmp_path, _flight(), "ok.csv")
    assert_rejected(capsys, tmp_path, ["ingest", flight, "--vehicle", vpath], str(vpath), *phrases)


def test_thesis_inertia_warns_with_the_fix(tmp_path, capsys):
    import yaml

    raw = yaml.safe_load(HB.read_text())
    raw["inertia"] = [0.00071, 0.00071, 0.017]  # thesis Table 4.1
    vpath = tmp_path / "thesis.yaml"
    vpath.write_text(yaml.safe_dump(raw))
    flight = _csv(tmp_path, _flight(), "ok.csv")
    status, _, err = run_cli(["ingest", flight, "--vehicle", vpath, "--out", tmp_path / "o.csv"], capsys)
    assert status == 0
    assert "qr: warning:" in err and "triangle inequality" in err and "fix:" in err
    assert (tmp_path / "o.csv").exists()


def test_unknown_effect_and_bad_synth_arguments(tmp_path, capsys):
    status, _, err = run_cli(["synth", "--vehicle", HB, "--effect", "linear_drg:kx=1", "--out", tmp_path / "s"],
                             capsys)
    assert status == 2 and "did you mean 'linear_drag'" in err and len(err.strip().splitlines()) == 1
    status, _, err = run_cli(["synth", "--vehicle", HB, "--effect", "linear_drag:kq=1", "--out", tmp_path / "s"],
                             capsys)
    assert status == 2 and "not a parameter of linear_drag" in err
    assert not (tmp_path / "s").exists()
