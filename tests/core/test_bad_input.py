"""Every unusable input: exit 2, one line naming the file, the problem and the fix, nothing written."""


import numpy as np
import pandas as pd
import pytest

from conftest import DATA, VEHICLES, run_cli
from conftest import small_flight as _flight

HB = VEHICLES / "asctec_hummingbird.yaml"


def assert_rejected(capsys, tmp_path, args, *phrases):
    out = tmp_path / "out" / "flight.csv"
    out.parent.mkdir(exist_ok=True)  # the folder an output goes in must exist (tests/core/test_output_safety.py)
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


def test_a_misspelt_optional_vehicle_key_warns_once_with_the_near_match(tmp_path, capsys):
    """Loaded, then extended (as qr diagnose does): one warning, naming the key it probably is."""
    import warnings

    import yaml

    from qr.vehicle import load_vehicle

    raw = yaml.safe_load(HB.read_text())
    raw["motor_time_constnt"] = raw.pop("motor_time_constant")
    vpath = tmp_path / "typo.yaml"
    vpath.write_text(yaml.safe_dump(raw))
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        v = load_vehicle(vpath)
        v.with_changes(effects=[{"name": "linear_drag", "parameters": {"kx": 0.1, "ky": 0.1, "kz": 0.1}}])
    assert len(seen) == 1, [str(w.message) for w in seen]
    assert "'motor_time_constnt' is probably 'motor_time_constant'" in str(seen[0].message)
    flight = _csv(tmp_path, _flight(), "ok.csv")
    status, _, err = run_cli(["ingest", flight, "--vehicle", vpath, "--out", tmp_path / "o.csv"], capsys)
    assert status == 0 and err.count("qr: warning:") == 1
    assert "unknown key(s) ['motor_time_constnt'] (ignored); fix: 'motor_time_constnt' is probably " \
           "'motor_time_constant': correct the spelling" in err


def test_unknown_effect_and_bad_synth_arguments(tmp_path, capsys):
    status, _, err = run_cli(["synth", "--vehicle", HB, "--effect", "linear_drg:kx=1", "--out", tmp_path / "s"],
                             capsys)
    assert status == 2 and "did you mean 'linear_drag'" in err and len(err.strip().splitlines()) == 1
    status, _, err = run_cli(["synth", "--vehicle", HB, "--effect", "linear_drag:kq=1", "--out", tmp_path / "s"],
                             capsys)
    assert status == 2 and "not a parameter of linear_drag" in err
    assert not (tmp_path / "s").exists()


# --- flight files that are not what their name says (read by content, or refused) ---

def test_folder_given_as_a_flight(tmp_path, capsys):
    folder = tmp_path / "flights"
    folder.mkdir()
    _flight().to_csv(folder / "a.csv", index=False)
    assert_rejected(capsys, tmp_path, ["ingest", folder, "--vehicle", HB], str(folder), "is a folder, not a log file")
    assert_rejected(capsys, tmp_path, ["summary", folder, "--vehicle", HB], str(folder),
                    "is a folder, not a flight file", "it holds a.csv")


def test_content_decides_the_format(tmp_path, hummingbird):
    """A gzip-compressed CSV, a CSV named .parquet and a Parquet named .csv read as what they are."""
    import gzip

    from qr.flight import REQUIRED, read_flight

    df = _flight()
    plain = _csv(tmp_path, df, "plain.csv")
    (tmp_path / "zipped.csv").write_bytes(gzip.compress(plain.read_bytes()))
    df.to_csv(tmp_path / "csv_named.parquet", index=False)
    df.to_parquet(tmp_path / "parquet_named.csv")
    (tmp_path / "bom.csv").write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())  # Excel's UTF-8 with BOM
    for name in ("zipped.csv", "csv_named.parquet", "parquet_named.csv", "bom.csv"):
        back = read_flight(tmp_path / name, hummingbird)
        pd.testing.assert_frame_equal(back[REQUIRED], df[REQUIRED], rtol=1e-8, obj=name)


@pytest.mark.parametrize("content, phrases", [
    ("random", ["is a binary file, not a CSV or Parquet flight"]),
    ("latin1", ["is not UTF-8 text (byte 0xe9 at line 1)", "save the CSV as UTF-8"]),
    ("utf16", ["is a binary file"]),
    ("damaged_gzip", ["gzip-compressed file is truncated or damaged"]),
    ("damaged_parquet", ["Parquet file cannot be read"]),
    ("zip", ["is a zip archive, not a CSV or Parquet flight"]),
])
def test_flight_file_that_is_not_a_csv(content, phrases, tmp_path, capsys):
    import gzip
    import io

    text = _flight().to_csv(index=False)
    if content == "random":
        data = np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes()
    elif content == "latin1":  # an extra column named in Latin-1
        data = text.replace("\n", ",café\n", 1).encode("latin-1")
    elif content == "utf16":
        data = text.encode("utf-16")
    elif content == "damaged_gzip":
        data = gzip.compress(text.encode())[:200]
    elif content == "damaged_parquet":
        buf = io.BytesIO()
        _flight().to_parquet(buf)
        data = buf.getvalue()[: len(buf.getvalue()) // 2]
    else:
        data = b"PK\x03\x04" + bytes(100)
    path = tmp_path / "flight.csv"
    path.write_bytes(data)
    assert_rejected(capsys, tmp_path, ["ingest", path, "--vehicle", HB], str(path), *phrases)


@pytest.mark.parametrize("sep, name", [(";", "semicolons"), ("\t", "tabs")])
def test_other_separators_are_named(sep, name, tmp_path, capsys):
    path = tmp_path / "flight.csv"
    _flight().to_csv(path, index=False, sep=sep)
    line = assert_rejected(capsys, tmp_path, ["ingest", path, "--vehicle", HB],
                           f"the cells are separated by {name}, not commas", "comma-separated")
    assert "missing column" not in line


def test_two_columns_with_the_same_name(tmp_path, capsys):
    df = _flight()
    df.insert(4, "px_again", df["px"] + 1.0)
    path = tmp_path / "flight.csv"
    path.write_text(df.to_csv(index=False).replace("px_again", "px", 1))
    assert path.read_text().splitlines()[0].split(",").count("px") == 2
    assert_rejected(capsys, tmp_path, ["ingest", path, "--vehicle", HB], "column(s) ['px'] appear more than once")


@pytest.mark.parametrize("edit, phrase", [
    (lambda lines: lines[:5] + [lines[5] + ",7"] + lines[6:], "line 6 has 13 cells, the header 12"),
    (lambda lines: lines[:-1] + [lines[-1][:9]], "has 2 cells, the header 12 (a truncated line?)"),
])
def test_rows_with_more_or_fewer_cells_than_the_header(edit, phrase, tmp_path, capsys):
    """pandas would shift or cut a longer row and pad a cut one with blanks (silently wrong numbers)."""
    path = tmp_path / "flight.csv"
    path.write_text("\n".join(edit(_flight().to_csv(index=False).splitlines())) + "\n")
    assert_rejected(capsys, tmp_path, ["ingest", path, "--vehicle", HB], phrase)


def test_non_finite_time_stamp(tmp_path, capsys):
    df = _flight()
    df["t"] = df["t"].astype(object)
    df.loc[7, "t"] = "1e999"  # parses as inf
    path = _csv(tmp_path, df)
    assert_rejected(capsys, tmp_path, ["ingest", path, "--vehicle", HB], "time stamp inf (not a number of seconds) at data row 8")


def test_frozen_attitude(tmp_path, capsys):
    """A quaternion identical in every sample is a frozen mocap stream (filter=auto crashed on it): refused."""
    df = _flight()
    df[["qw", "qx", "qy", "qz"]] = [1.0, 0.0, 0.0, 0.0]
    path = _csv(tmp_path, df)
    assert_rejected(capsys, tmp_path, ["ingest", path, "--vehicle", HB],
                    "every sample has the same attitude (qw, qx, qy, qz)", "frozen stream")


def test_one_row_flight_for_summary(tmp_path, capsys):
    path = _csv(tmp_path, _flight().iloc[:1])
    assert_rejected(capsys, tmp_path, ["summary", path, "--vehicle", HB], str(path), "flight has only 1 sample")
    path = _csv(tmp_path, _flight().iloc[:20], "short.csv")  # 0.2 s at 100 Hz: shorter than the 21-sample window
    assert_rejected(capsys, tmp_path, ["summary", path, "--vehicle", HB], "need at least 21")


# --- vehicle files ---

def _vehicle_file(tmp_path, raw=None, text=None, name="vehicle.yaml"):
    import yaml

    p = tmp_path / name
    if text is not None:
        p.write_bytes(text if isinstance(text, bytes) else text.encode())
    else:
        p.write_text(yaml.safe_dump(raw, sort_keys=False))
    return p


def _hb_raw():
    import yaml

    return yaml.safe_load(HB.read_text())


def _assert_bad_vehicle(capsys, tmp_path, vpath, *phrases):
    flight = _csv(tmp_path, _flight(), "ok.csv")
    return assert_rejected(capsys, tmp_path, ["ingest", flight, "--vehicle", vpath], *phrases)


def test_vehicle_not_utf8(tmp_path, capsys):
    v = _vehicle_file(tmp_path, text=HB.read_bytes().replace(b"name: asctec-hummingbird", b"name: caf\xe9"))
    line = HB.read_bytes()[:HB.read_bytes().index(b"name:")].count(b"\n") + 1
    _assert_bad_vehicle(capsys, tmp_path, v, str(v), f"not UTF-8 text (byte 0xe9 at line {line})")


def test_vehicle_folder(tmp_path, capsys):
    (tmp_path / "v").mkdir()
    _assert_bad_vehicle(capsys, tmp_path, tmp_path / "v", "is a folder, not a vehicle file")


def test_extends_cycles(tmp_path, capsys):
    me = _vehicle_file(tmp_path, text="extends: self.yaml\nmass: 0.7\n", name="self.yaml")
    _assert_bad_vehicle(capsys, tmp_path, me, "'extends: self.yaml' makes a cycle (self.yaml -> self.yaml)")
    a = _vehicle_file(tmp_path, text="extends: b.yaml\nmass: 0.7\n", name="a.yaml")
    _vehicle_file(tmp_path, text="extends: a.yaml\n", name="b.yaml")
    _assert_bad_vehicle(capsys, tmp_path, a, "makes a cycle (a.yaml -> b.yaml -> a.yaml)")


def test_extends_missing_or_not_a_name(tmp_path, capsys):
    v = _vehicle_file(tmp_path, text="extends: nowhere.yaml\nmass: 0.7\n")
    _assert_bad_vehicle(capsys, tmp_path, v, str(v), "'extends: nowhere.yaml' names", "which does not exist")
    v = _vehicle_file(tmp_path, text="extends: [a, b]\nmass: 0.7\n")
    _assert_bad_vehicle(capsys, tmp_path, v, "is not a file name")


@pytest.mark.parametrize("key, value", [("x", "a"), ("y", [0.1]), ("yaw_sign", "one"),
                                        ("yaw_sign", True)])
def test_non_numeric_layout_entry(key, value, tmp_path, capsys):
    raw = _hb_raw()
    raw["layout"] = [{"x": x, "y": y, "yaw_sign": s}
                     for x, y, s in [(0.17, 0, -1), (0, 0.17, 1), (-0.17, 0, -1), (0, -0.17, 1)]]
    raw["layout"][2][key] = value
    v = _vehicle_file(tmp_path, raw)
    _assert_bad_vehicle(capsys, tmp_path, v, f"layout rotor 3 has {key}:", "not a number")


@pytest.mark.parametrize("key, value, phrase", [
    ("mass", True, "'mass' is True, not a number"),
    ("mass", "0.7", "'mass' is '0.7', not a number"),
    ("thrust_coeff", [4.9e-8], "'thrust_coeff' is [4.9e-08], not a number"),
    ("arm_length", None, "'arm_length' is None, not a number"),
    ("inertia", [0.007, True, 0.012], "'inertia' is [0.007, True, 0.012], not three numbers"),
    ("motor_time_constant", False, "'motor_time_constant' is False, not a number"),
    ("rotor_speed_min", -5, "'rotor_speed_min' is -5, below 0"),
])
def test_vehicle_numbers_must_be_numbers(key, value, phrase, tmp_path, capsys):
    raw = _hb_raw()
    raw[key] = value
    _assert_bad_vehicle(capsys, tmp_path, _vehicle_file(tmp_path, raw), phrase)


def test_exponent_without_a_dot_is_a_number(tmp_path):
    """PyYAML reads `1e-8` (no dot) as a string; the vehicle reader takes it as the number it is."""
    from qr.vehicle import load_vehicle

    text = HB.read_text().replace("thrust_coeff: 4.9782e-8", "thrust_coeff: 49782e-12")
    assert "49782e-12" in text
    v = load_vehicle(_vehicle_file(tmp_path, text=text))
    assert v.thrust_coeff == pytest.approx(4.9782e-8, rel=1e-12)


@pytest.mark.parametrize("effects, phrases", [
    ([{"name": "linear_drag"}], ["effect linear_drag lacks parameter(s) kx, ky, kz (none given)",
                                 "kx, ky, kz each in [0, 14] N s/m"]),
    ([{"name": "linear_drag", "parameters": {"kx": 0.3}}], ["lacks parameter(s) ky, kz (only kx given)"]),
    ([{"name": "linear_drag", "parameters": {"kx": "abc", "ky": 0, "kz": 0}}],
     ["effect linear_drag parameter kx is 'abc', not a finite number"]),
    ([{"name": "thrust_gain", "parameters": {"gain": True}}], ["parameter gain is True, not a finite number"]),
    ([{"name": "thrust_gain", "parameters": {"gain": -5}}],
     ["parameter gain=-5 is outside the range [0.333, 3]", "gain in [0.333, 3] (no effect: gain=1)"]),
    ([{"name": "linear_drag", "parameters": [0.3, 0.3, 0.1]}], ["not a mapping of names to values"]),
    (["linear_drag"], ["effect entry 'linear_drag' is not a mapping with a name"]),
])
def test_vehicle_effects_are_checked(effects, phrases, tmp_path, capsys):
    raw = _hb_raw()
    raw["effects"] = effects
    v = _vehicle_file(tmp_path, raw)
    _assert_bad_vehicle(capsys, tmp_path, v, str(v), *phrases)


# --- qr synth arguments ---

@pytest.mark.parametrize("option, value, phrase", [
    ("--position-noise", "-0.001", "--position-noise: -0.001 is out of range: it must be a number >= 0"),
    ("--attitude-noise", "nan", "--attitude-noise: nan is out of range: it must be a number >= 0"),
    ("--rotor-noise", "-1", "--rotor-noise: -1 is out of range"),
    ("--dropout", "1.0", "--dropout: 1 is out of range: it must be a number in [0, 1)"),
    ("--dropout", "-0.1", "--dropout: -0.1 is out of range"),
    ("--duration", "0", "--duration: 0 is out of range: it must be a number in (0, 3600]"),
    ("--rate", "1e9", "--rate: 1e+09 is out of range: it must be a number in (0, 10000]"),
    ("--tilt-max", "100", "--tilt-max: 100 is out of range: it must be a number in [0, 60]"),
    ("--v-max", "-1", "--v-max: -1 is out of range"),
    ("--yaw-rate", "inf", "--yaw-rate: inf is out of range: it must be a finite number"),
    ("--seed", "-1", "--seed: -1 is out of range: it must be an integer >= 0"),
])
def test_synth_arguments_in_range(option, value, phrase, tmp_path, capsys):
    line = assert_rejected(capsys, tmp_path, ["synth", "--vehicle", HB, "--duration", "5", option, value], phrase)
    assert f"e.g. {option}=" in line  # the fix shows the default


def test_synth_high_dropout_ends_and_keeps_first_and_last_rows(tmp_path, capsys):
    status, _, err = run_cli(["synth", "--vehicle", HB, "--duration", "2", "--dropout", "0.999",
                              "--out", tmp_path / "s"], capsys)
    assert status == 0, err
    flight = pd.read_csv(tmp_path / "s" / "flight.csv")
    blank = flight[["px", "qw"]].isna().any(axis=1).to_numpy()
    assert len(flight) == 201
    assert not blank[0] and not blank[-1]
    assert blank.sum() == 201 - 3  # every row a burst can reach (rows 1 .. n-3)


@pytest.mark.parametrize("spec, phrases", [
    ("linear_drag", ["effect linear_drag lacks parameter(s) kx, ky, kz (none given)",
                     "--effect linear_drag:kx=VALUE,ky=VALUE,kz=VALUE", "kx, ky, kz each in [0, 14] N s/m"]),
    ("linear_drag:kx=0.3", ["lacks parameter(s) ky, kz (only kx given)", "kx, ky, kz each in [0, 14] N s/m"]),
    ("thrust_gain:gain=-5", ["parameter gain=-5 is outside the range [0.333, 3]",
                             "gain in [0.333, 3] (no effect: gain=1)"]),
    ("cg_offset:rx=0.5,ry=0", ["rx=0.5 is outside the range [-0.085, 0.085]"]),  # half the 0.17 m arm
    ("linear_drag:kx=abc,ky=0,kz=0", ["linear_drag parameter kx='abc' is not a number"]),
    ("linear_drag:kx=nan,ky=0,kz=0", ["parameter kx is nan, not a finite number"]),
])
def test_synth_effect_parameters(spec, phrases, tmp_path, capsys):
    assert_rejected(capsys, tmp_path, ["synth", "--vehicle", HB, "--duration", "5", "--effect", spec],
                    "--effect: ", *phrases)


@pytest.mark.parametrize("file_unit", ["rpm", "rad_s"])
def test_the_other_speed_unit_hint_gives_the_whole_fix(file_unit, tmp_path, capsys):
    """Speeds logged in the other unit: the hint's coefficients are the file's x (60/2π)² (or its inverse), and
    either fix it names makes the flight pass with the thrust it should have."""
    import re

    import yaml

    from qr.flight import hover_ratio, read_flight
    from qr.vehicle import load_vehicle

    raw = yaml.safe_load(HB.read_text())
    k = 60 / (2 * np.pi) if file_unit == "rpm" else 2 * np.pi / 60  # one unit of the other, in the file's
    df = _flight()
    if file_unit == "rad_s":  # the same vehicle, its file in rad/s: C_T and C_Q per (rad/s)²
        rpm2 = (60 / (2 * np.pi))**2  # (rpm per rad/s)²
        raw.update(rotor_speed_unit="rad_s", thrust_coeff=raw["thrust_coeff"] * rpm2,
                   torque_coeff=raw["torque_coeff"] * rpm2)
        df[["u1", "u2", "u3", "u4"]] *= 2 * np.pi / 60
    vfile = tmp_path / "v.yaml"
    vfile.write_text(yaml.safe_dump(raw))
    good = hover_ratio(df, load_vehicle(vfile))
    wrong = df.assign(**{u: df[u] / k for u in ["u1", "u2", "u3", "u4"]})  # logged in the other unit
    path = _csv(tmp_path, wrong)
    line = assert_rejected(capsys, tmp_path, ["ingest", path, "--vehicle", vfile], "unit or coefficient error")
    other = "rad_s" if file_unit == "rpm" else "rpm"
    assert f"the speeds look like {other}, not {file_unit}" in line, line
    m = re.search(rf"multiply u1..u4 by \S+ = (\S+) .*set rotor_speed_unit: {other} in the vehicle file together "
                  r"with thrust_coeff: (\S+) and torque_coeff: (\S+) \(C_T and C_Q are per unit², so both x \(\S+\)² = "
                  r"(\S+): now (\S+) and (\S+)\)", line)
    assert m, line
    scale, ct, cq, k2, ct0, cq0 = map(float, m.groups())
    assert scale == pytest.approx(k, rel=1e-5) and k2 == pytest.approx(k**2, rel=1e-5)
    assert ct == pytest.approx(raw["thrust_coeff"] * k**2, rel=1e-5)
    assert cq == pytest.approx(raw["torque_coeff"] * k**2, rel=1e-5)
    assert (ct0, cq0) == (pytest.approx(raw["thrust_coeff"], rel=1e-5), pytest.approx(raw["torque_coeff"], rel=1e-5))
    # the file switched as the hint says: the log passes with the thrust of the right units
    fixed = tmp_path / "fixed.yaml"
    fixed.write_text(yaml.safe_dump({**raw, "rotor_speed_unit": other, "thrust_coeff": ct, "torque_coeff": cq}))
    veh = load_vehicle(fixed)
    assert hover_ratio(read_flight(path, veh), veh) == pytest.approx(good, rel=1e-5)
    # ... or the log converted: the same
    assert hover_ratio(wrong.assign(**{u: wrong[u] * scale for u in ["u1", "u2", "u3", "u4"]}),
                       load_vehicle(vfile)) == pytest.approx(good, rel=1e-5)


@pytest.mark.parametrize("args, phrase", [
    (["diagnose", "f.csv", "--out", "d"], "the following arguments are required: --vehicle"),
    (["evaluate", "f.csv", "--vehicle", str(HB), "--out", "e", "--bogus"], "unrecognized arguments: --bogus"),
    (["learn", "residual", "f.csv", "--vehicle", str(HB)], "the following arguments are required: --out"),
    (["export", str(HB), "--out", "x"], "the following arguments are required: --to"),
    (["replay", "f.csv", "--out", "r"], "the following arguments are required: --vehicle, --controller"),
    (["nosuch"], "invalid choice: 'nosuch'"),
])
def test_a_command_line_error_is_one_line_with_its_fix(args, phrase, tmp_path, capsys, monkeypatch):
    """A missing or unknown option is bad input too (the specs: exit 2, one line on standard error): the
    problem and the command's --help as the fix, not argparse's usage block; nothing is written."""
    from qr.cli import main

    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:
        main(args)
    err = capsys.readouterr().err
    assert e.value.code == 2
    assert err.count("\n") == 1 and err.endswith("\n"), err
    prog = " ".join(["qr", *args[:2]]) if args[:2] == ["learn", "residual"] else \
        ("qr" if args[0] == "nosuch" else f"qr {args[0]}")
    assert err.startswith(f"{prog}: error: ") and phrase in err and err.rstrip().endswith(f"fix: see '{prog} --help'"), err
    assert list(tmp_path.iterdir()) == []
