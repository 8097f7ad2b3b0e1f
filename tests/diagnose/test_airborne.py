"""Ground rows, time gaps and infinite values: handled so the diagnosis means what it says, or refused.

A real log starts and ends on the ground (motors off, idling, spinning up): those rows must never reach
the fit.  A long gap in the time stamps splits a flight into segments that are filtered, replayed and
cut into blocks on their own, with no train/test boundary across a gap.  An infinite sensor value is a
dropout of that sensor.  The diagnosis-level checks share one 40 s synthetic drag flight.
"""

import json

import numpy as np
import pandas as pd
import pytest

from conftest import DATA, VEHICLES, run_cli
from qr.airborne import airborne_windows, check_airborne
from qr.stages.diagnose import run_diagnosis
from qr.effects import parse_effect_spec
from qr.errors import QrInputError, QrInputWarning
from qr.segments import flight_segments, gap_threshold
from qr.sim.synth import SynthConfig, simulate_truth, synthesize, write_synth
from qr.vehicle import load_vehicle
from conftest import ground_rows as _ground, on_the_ground as _on_the_ground, small_flight as _flight

HB = VEHICLES / "asctec_hummingbird.yaml"
DRAG = "linear_drag:kx=0.3,ky=0.3,kz=0.15"
RATE = 100.0


# ------------------------------------------------------------------ the detector


def test_ground_rows_before_and_after_are_found_exactly(hummingbird):
    flight, _ = synthesize(hummingbird, [], SynthConfig(duration=8, rate=RATE, seed=1))
    log, window = _on_the_ground(flight, hummingbird, before_s=6, spin_up_s=2)
    assert airborne_windows(log, hummingbird) == [pytest.approx(window, abs=1e-9)]
    # dropouts in the rotor speeds and the mocap change nothing
    holes = log.copy()
    holes.loc[holes.index % 7 == 0, ["u1", "u3"]] = np.nan
    holes.loc[holes.index % 11 == 0, ["px", "py", "pz"]] = np.nan
    assert airborne_windows(holes, hummingbird) == [pytest.approx(window, abs=1e-9)]


def test_a_short_low_thrust_manoeuvre_is_flight_a_hop_is_not(hummingbird):
    df = _flight(3000)  # 30 s at hover thrust, moving, no rest anywhere
    dip = df.copy()
    dip.loc[1000:1020, ["u1", "u2", "u3", "u4"]] *= 0.3  # 0.2 s at 0.09 m g: a fast descent
    assert airborne_windows(dip, hummingbird) == [(0.0, pytest.approx(29.99))]
    # a vehicle that spins up on the floor and never rises: nothing airborne
    up = _ground(1000, [0, 0, 0.05], np.sqrt(0.95) * hummingbird.hover_speed, 0.0)
    up.loc[:300, ["u1", "u2", "u3", "u4"]] = 0.0
    assert airborne_windows(up, hummingbird) == []


@pytest.mark.skipif(not DATA.exists(), reason="measured data not available")
def test_the_measured_logs_are_airborne_throughout(crazyflie):
    """The IMRCLab logs start and end in hover: nothing of them is ground."""
    from qr.flight import validate_flight
    from qr.ingest.cf_usd import read

    for name in ("eckart00", "eckart17", "eckart36"):
        df = validate_flight(read(DATA / "brushless_flights" / "data" / name))
        assert airborne_windows(df, crazyflie) == [(df["t"].iloc[0], df["t"].iloc[-1])], name


def test_units_are_still_checked_on_a_log_mostly_on_the_ground(hummingbird):
    """The rotor-speed unit check looks at the rows where the rotors work, not at the idle ones."""
    log, _ = _on_the_ground(_flight(1000), hummingbird, before_s=30, after_s=0.5)  # 10 s flight, 30 s ground
    assert check_airborne(log, hummingbird) == [(30.0, pytest.approx(39.99))]
    wrong = log.assign(**{u: log[u] * 2 * np.pi / 60 for u in ["u1", "u2", "u3", "u4"]})
    with pytest.raises(QrInputError, match="look like rad_s"):
        check_airborne(wrong, hummingbird)


# ------------------------------------------------------------------ refusals


def _assert_refused(capsys, tmp_path, path, *phrases):
    out = tmp_path / "diag"
    status, _, err = run_cli(["diagnose", path, "--vehicle", HB, "--out", out], capsys)
    lines = err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and lines[0].startswith("qr: error: ") and "fix:" in lines[0], err
    for p in phrases:
        assert p in lines[0], (p, lines[0])
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".diag")]


@pytest.mark.parametrize("case, phrase", [
    ("idling", "never airborne: the position never changes by more than 5 cm"),
    ("carried", "never airborne: the rotor-map thrust never exceeds 0.5 x m g"),
])
def test_a_vehicle_that_never_flies_is_refused(case, phrase, tmp_path, capsys, hummingbird):
    if case == "idling":  # 60 s on the floor, motors idling
        df = _ground(6000, [0.3, -0.2, 0.05], 0.2 * hummingbird.hover_speed, 0.0)
    else:  # motors off, carried 2 m through the room
        df = _ground(6000, [0.0, 0.0, 1.0], 0.0, 0.0)
        df["px"] += np.linspace(0, 2, len(df))
    path = tmp_path / "ground.csv"
    df.to_csv(path, index=False)
    _assert_refused(capsys, tmp_path, path, phrase, "ground.csv")


@pytest.mark.parametrize("every_s, phrase", [
    (2.0, "no airborne stretch without a time gap lasts 3.0 s (2 trim_s + block_s; the longest: 1.8 s)"),
    (10.0, "flight lasts 58.7 s airborne in 6 segments between time gaps, too short to hold out a test part "
           "(needs 63.9 s)"),
])
def test_a_flight_chopped_by_gaps_is_refused_when_too_little_is_left(every_s, phrase, tmp_path, capsys):
    """2 s pieces are all shorter than a segment must be (2 x 0.5 s + 2 s); with diagnose.block_s=8, five
    training blocks and half the gap need (5 x 8 + 0.5) / 0.7 = 57.9 s, six 9.79 s segments leave 6 x 8.79 s."""
    df = _flight(6000).round({"t": 6})
    k = int(round(every_s * RATE))
    df = df[np.arange(len(df)) % k < k - 20]  # 0.2 s missing every `every_s`
    path = tmp_path / "chopped.csv"
    df.to_csv(path, index=False)
    out = tmp_path / "diag"
    overrides = ["diagnose.block_s=8"] if every_s > 5 else []
    status, _, err = run_cli(["diagnose", path, *overrides, "--vehicle", HB, "--out", out], capsys)
    assert status == 2 and len(err.strip().splitlines()) == 1 and phrase in err, err
    assert not out.exists()


@pytest.mark.parametrize("scale, unit, fix", [(1e3, "milliseconds", "divide t by 1000"),
                                              (1e6, "microseconds", "divide t by 1e6")])
def test_time_stamps_not_in_seconds_are_refused(scale, unit, fix, tmp_path, capsys):
    df = _flight(6000)
    df["t"] *= scale
    path = tmp_path / "clock.csv"
    df.to_csv(path, index=False)
    _assert_refused(capsys, tmp_path, path, f"time stamps look like {unit}, not seconds", fix,
                    "0.01 s per sample in seconds")
    status, _, err = run_cli(["ingest", path, "--vehicle", HB, "--out", tmp_path / "c.csv"], capsys)
    assert status == 2 and unit in err and not (tmp_path / "c.csv").exists()


def test_an_infinite_time_stamp_is_refused(tmp_path, capsys):
    df = _flight(6000)
    df.loc[5999, "t"] = np.inf
    path = tmp_path / "inf_t.csv"
    df.to_csv(path, index=False)
    _assert_refused(capsys, tmp_path, path, "time stamp inf (not a number of seconds) at data row 6000")


def test_infinite_sensor_values_are_dropouts_with_one_warning(tmp_path, capsys):
    df = _flight(500)
    df.loc[[10, 11, 300], "u2"] = np.inf
    df.loc[40, "u4"] = -np.inf
    df.loc[50, "qx"] = np.inf
    df.loc[60, "pz"] = np.inf
    path = tmp_path / "inf.csv"
    df.to_csv(path, index=False)
    status, _, err = run_cli(["ingest", path, "--vehicle", HB, "--out", tmp_path / "clean.csv"], capsys)
    assert status == 0
    warnings = [line for line in err.splitlines() if line.startswith("qr: warning:")]
    assert len(warnings) == 1 and "6 infinite value(s) in pz (1), qx (1), u2 (3), u4 (1)" in warnings[0], err
    assert "first at data row 11 (t=0.100)" in warnings[0]
    clean = pd.read_csv(tmp_path / "clean.csv")
    assert np.isfinite(clean.drop(index=[10, 11, 300, 40, 50, 60])[["px", "py", "pz", "qw", "qx", "qy", "qz",
                                                                       "u1", "u2", "u3", "u4"]]).all().all()
    assert clean.loc[[10, 11, 300], "u2"].isna().all() and np.isnan(clean.loc[40, "u4"])
    assert clean.loc[50, ["qw", "qx", "qy", "qz"]].isna().all() and np.isnan(clean.loc[60, "pz"])


# ------------------------------------------------------------------ gaps, unit level


def test_gaps_split_the_airborne_part_into_segments(hummingbird):
    df = _flight(6000).round({"t": 6})
    t = df["t"].to_numpy()
    assert gap_threshold(t) == pytest.approx(0.1)  # 10 samples at 100 Hz
    cut = df[((t < 20) | (t >= 22)) & ((t < 40) | (t >= 40.5)) & ((t < 41.2) | (t >= 41.35))]
    fs = flight_segments(cut.reset_index(drop=True), hummingbird, min_s=3.0)
    assert fs.gaps == [(19.99, 22.0), (39.99, 40.5), (41.19, 41.35)]
    assert [(s.window, s.used) for s in fs.segments] == [
        ((0.0, 19.99), True), ((22.0, 39.99), True), ((40.5, 41.19), False), ((41.35, 59.99), True)]
    assert "shorter than the 3.00 s a segment needs" in fs.segments[2].note
    assert fs.ground_s == 0.0
    # a step of 9 samples is a dropout the filters bridge, not a gap
    assert flight_segments(df.drop(index=range(100, 108)), hummingbird, 3.0).gaps == []


def test_the_learning_table_leaves_the_ground_rows_out(hummingbird):
    from qr.datasets import flight_table

    truth = simulate_truth(hummingbird, [parse_effect_spec(DRAG)], SynthConfig(duration=6.0, seed=2))
    rest = pd.DataFrame(0.0, index=range(300), columns=truth.columns)
    rest["t"] = np.arange(300) / RATE
    rest[["px", "py", "pz", "qw"]] = [truth["px"].iloc[0], truth["py"].iloc[0], 0.05, 1.0]
    log = pd.concat([rest, truth.assign(t=truth["t"] + 3.0)], ignore_index=True)
    table = flight_table(log, hummingbird, "f")
    assert len(table) == len(truth) and table["t"].iloc[0] == 3.0
    # on the floor f_a would be the floor's support, +m g; in the air only the drag is left
    assert table["f_a.z"].abs().max() < 0.2 * hummingbird.mass * 9.81


# ------------------------------------------------------------------ the diagnosis


@pytest.fixture(scope="module")
def drag_flight(tmp_path_factory):
    """A 40 s, 100 Hz Hummingbird flight with linear drag hidden, its clean diagnosis."""
    d = tmp_path_factory.mktemp("drag")
    write_synth(d / "s", load_vehicle(HB), [parse_effect_spec(DRAG)], SynthConfig(duration=40, rate=RATE, seed=3))
    doc = run_diagnosis([d / "s" / "flight.csv"], d / "s" / "vehicle.yaml", d / "clean", log=lambda m: None,
                        figures=False)
    assert [e["name"] for e in doc["effects"]] == ["linear_drag"]
    return d, pd.read_csv(d / "s" / "flight.csv"), doc


def _diagnose(d, df, name, **kw):
    df.to_csv(d / f"{name}.csv", index=False)
    return run_diagnosis([d / f"{name}.csv"], d / "s" / "vehicle.yaml", d / name, log=lambda m: None,
                         figures=False, **kw)


def test_ground_rows_change_nothing_and_the_window_is_reported(drag_flight):
    d, flight, clean = drag_flight
    log, window = _on_the_ground(flight, load_vehicle(HB), spin_up_s=2.0)
    doc = _diagnose(d, log, "ground")
    assert doc["airborne"] == [{"flight": str(d / "ground.csv"), "window": [5.0, 45.0], "dropped_s": 10.0}]
    # the same rows are fitted: the same effect, the same numbers
    assert [e["name"] for e in doc["effects"]] == ["linear_drag"]
    for k, v in clean["effects"][0]["parameters"].items():
        assert doc["effects"][0]["parameters"][k] == pytest.approx(v, rel=1e-4)
    for k in ("force_rmse", "torque_rmse"):
        assert doc["nominal"][k] == pytest.approx(clean["nominal"][k], rel=1e-4)
    # windows in the file's own time: shifted by the 5 s of ground before take-off
    for part in ("train", "test"):
        assert doc["split"][part] == pytest.approx([x + 5.0 for x in clean["split"][part]], abs=1e-3)
    report = (d / "ground" / "report.md").read_text()
    assert f"`{d / 'ground.csv'}`: airborne 5.00-45.00 s; 10.0 s on the ground left out" in report


def test_a_time_gap_splits_the_flight_and_nothing_straddles_it(drag_flight):
    d, flight, _ = drag_flight
    t = flight["t"].to_numpy()
    doc, res = _diagnose(d, flight[(t < 20) | (t >= 22)], "gap", return_result=True)
    assert doc["time_gaps"] == [{"flight": str(d / "gap.csv"), "from": 19.99, "to": 22.0}]
    assert [s["window"] for s in doc["segments"]] == [[0.0, 19.99], [22.0, 40.0]]
    assert "no samples from 19.99 to 22.00 s" in (d / "gap" / "report.md").read_text()
    prep = res.labels.full
    for i in np.unique(prep.flight):  # each filtered state table lies on one side of the gap
        ti = prep.t[prep.flight == i]
        assert ti.max() < 20 or ti.min() >= 22
    # one train/test cut per flight, inside a segment, gap_s between the parts
    (tr0, tr1), (te0, te1) = doc["split"]["train"], doc["split"]["test"]
    assert te0 - tr1 == pytest.approx(1.0) and not (19.99 < tr1 < 22 or 19.99 < te0 < 22)
    assert prep.t[prep.train].max() < te0 - 1.0 + 1e-9 and prep.t[prep.test].min() >= te0
    assert prep.t[prep.train].min() >= 0.5 and prep.t[prep.test].max() <= 39.5  # trim_s at segment ends
    assert not ((prep.t > 19.49) & (prep.t < 22.5)).any()  # ... and at the gap's two sides
    for key in ("nominal", "extended"):  # no replay window runs across the gap
        err = getattr(res.replay, key).errors
        span = err.groupby("window")["t"].agg(["min", "max"])
        assert ((span["max"] < 20) | (span["min"] >= 22)).all()
    assert np.isfinite(doc["nominal"]["force_rmse"] + doc["extended"]["force_rmse"]).all()
    k = doc["effects"][0]
    assert k["name"] == "linear_drag" and k["parameters"]["kx"] == pytest.approx(0.3, rel=0.05)


def test_an_infinite_rotor_speed_is_a_dropout_not_a_nan_everywhere(drag_flight):
    d, flight, clean = drag_flight
    bad = flight.copy()
    bad.loc[[1000, 1001, 2500], "u2"] = np.inf
    bad.loc[3000, "px"] = -np.inf
    with pytest.warns(QrInputWarning, match="4 infinite value"):
        doc = _diagnose(d, bad, "inf")
    for key in ("nominal", "extended", "noise_floor"):
        assert np.isfinite(doc[key]["force_rmse"] + doc[key]["torque_rmse"]).all(), key
    assert np.isfinite(doc["replay"]["nominal_position_rmse"])
    assert [e["name"] for e in doc["effects"]] == ["linear_drag"]
    assert doc["nominal"]["force_rmse"] == pytest.approx(clean["nominal"]["force_rmse"], rel=0.01)
    json.dumps(doc, allow_nan=False)
