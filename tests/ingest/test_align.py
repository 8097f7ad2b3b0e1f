"""Stream alignment (``qr.ingest.align``): a known offset between the motion capture and the gyro or the
rotor stream of a synthetic flight is found and undone; on the measured Crazyflie flights the rotor
offsets agree across flights and with the motors' response measured without the motion capture."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest

from conftest import DATA, VEHICLES, run_cli
from qr.effects import parse_effect_spec
from qr.ingest import align
from qr.sim.synth import SynthConfig, write_synth
from qr.vehicle import load_vehicle

HB = VEHICLES / "asctec_hummingbird.yaml"
SAMPLE = 0.01  # s at 100 Hz


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    d = tmp_path_factory.mktemp("align")
    write_synth(d, load_vehicle(HB), [parse_effect_spec("linear_drag:kx=0.3,ky=0.3,kz=0.15")],
                SynthConfig(duration=60, seed=4))
    fl, truth = pd.read_csv(d / "flight.csv"), pd.read_parquet(d / "truth.parquet")
    rng = np.random.default_rng(4)
    for a in "xyz":  # a gyro: the true body rate with white noise and a bias
        fl[f"g{a}"] = truth[f"w{a}"].to_numpy() + 0.02 * rng.standard_normal(len(fl)) + 0.01
    return fl


def _stamped(fl, by, cols=("gx", "gy", "gz")):
    """The stream ``cols`` stamped ``by`` seconds late: logged(t) = true(t - by)."""
    t, out = fl["t"].to_numpy(), fl.copy()
    for c in cols:
        out[c] = np.interp(t - by, t, fl[c].to_numpy(), left=np.nan, right=np.nan)
    return out


@pytest.mark.parametrize("late", [-0.02, 0.0, 0.035, 0.1])
def test_a_known_gyro_offset_is_found_to_a_sample(flight, late):
    found = align.offsets(_stamped(flight, late))["gyro"]
    assert found["offset_s"] == pytest.approx(late, abs=SAMPLE)
    assert found["correlation"] > 0.9


def test_moving_the_gyro_undoes_the_offset(flight):
    off = _stamped(flight, 0.05)
    moved = align.apply(off, align.offsets(off))
    assert abs(align.offsets(moved)["gyro"]["offset_s"]) < SAMPLE
    assert moved["gx"].iloc[-3:].isna().all()  # the rows the moved stream does not reach are dropouts
    assert align.offsets(flight.drop(columns=["gx", "gy", "gz"])) == {}  # no gyro, nothing to align


def test_qr_ingest_reports_the_offset_and_moves_only_when_asked(flight, tmp_path, capsys):
    src = tmp_path / "late.csv"
    _stamped(flight, 0.05).dropna().to_csv(src, index=False)
    status, out, err = run_cli(["ingest", src, "--vehicle", HB, "--out", tmp_path / "a.parquet"], capsys)
    assert status == 0, err
    assert float(re.search(r"gyro stamped ([0-9.]+) ms late", out).group(1)) == pytest.approx(50, abs=5)
    assert "moved" not in out
    kept = pd.read_parquet(tmp_path / "a.parquet")
    assert kept["gx"].to_numpy() == pytest.approx(pd.read_csv(src)["gx"].to_numpy())
    status, out, err = run_cli(["ingest", src, "--vehicle", HB, "--out", tmp_path / "b.parquet", "--align"], capsys)
    assert status == 0, err
    assert "moved" in out
    moved = pd.read_parquet(tmp_path / "b.parquet")
    assert abs(align.offsets(moved)["gyro"]["offset_s"]) < SAMPLE


ROTORS = ("u1", "u2", "u3", "u4")
# Aerodynamic forces and torques that move the vertical-thrust channel's peak (a drag along every body
# axis, blade flapping: torques along the velocity), a CG offset (a torque along the thrust) and a
# physical rotor delay, which is part of the rotor stream's lag by definition.
CLEAN = {"aero": ("linear_drag:kx=0.3,ky=0.3,kz=0.15", "blade_flapping:k=0.05"),
         "delayed": ("linear_drag:kx=0.3,ky=0.3,kz=0.15", "cg_offset:rx=0.01,ry=-0.005",
                     "actuator_delay:delay_s=0.02")}


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """Noise-free synthetic flights (the estimator's bias alone, no sampling error)."""
    out = {}
    for name, specs in CLEAN.items():
        d = tmp_path_factory.mktemp(name)
        write_synth(d, load_vehicle(HB), [parse_effect_spec(e) for e in specs],
                    SynthConfig(duration=60, seed=1, noise_free=True))
        out[name] = pd.read_csv(d / "flight.csv")
    return out


@pytest.mark.parametrize("name, delay", [("aero", 0.0), ("delayed", 0.02)])
@pytest.mark.parametrize("late", [-0.02, 0.0, 0.035, 0.1])
def test_a_known_rotor_offset_is_found_through_drag_flapping_and_a_cg_offset(clean, name, delay, late):
    """The rotor stream's lag is its stamping offset minus the plant's own rotor delay: found to half a
    sample although every aerodynamic effect of the flight is there (the thrust channel was 66 ms off)."""
    found = align.offsets(_stamped(clean[name], late, ROTORS), load_vehicle(HB))["rotors"]
    assert found["offset_s"] == pytest.approx(late - delay, abs=SAMPLE / 2)
    assert found["correlation"] > 0.9
    assert "rotors" not in align.offsets(clean[name])  # without the vehicle there is no rotor map


def test_qr_ingest_moves_the_rotor_stream_when_asked(clean, tmp_path, capsys):
    src = tmp_path / "late.csv"
    _stamped(clean["aero"], 0.05, ROTORS).dropna().to_csv(src, index=False)
    status, out, err = run_cli(["ingest", src, "--vehicle", HB, "--out", tmp_path / "a.csv", "--align"], capsys)
    assert status == 0, err
    assert float(re.search(r"rotors stamped ([0-9.]+) ms late", out).group(1)) == pytest.approx(50, abs=5)
    assert "moved" in out
    moved = pd.read_csv(tmp_path / "a.csv")
    assert align.offsets(moved, load_vehicle(HB))["rotors"]["offset_s"] == pytest.approx(0.0, abs=SAMPLE / 2)


CF_FLIGHTS = ("eckart00", "eckart01", "eckart02", "eckart03", "eckart04", "eckart06")


@pytest.mark.skipif(not (DATA / "brushless_flights").exists(), reason="measured Crazyflie data not present")
def test_measured_rotor_offsets_agree_across_flights_and_with_the_motor_response():
    """The Crazyflie logs carry the rpm and the PWM of the same rotors. One setup has one clock relation,
    so the rpm stream's offset is the same on every flight; and the PWM stream's offset exceeds it by the
    motors' response, which the two on-board streams give directly (PWM thrust against rpm thrust, no
    motion capture in it)."""
    from qr.ingest import read_log

    rpm_v, pwm_v = load_vehicle("crazyflie21_brushless"), load_vehicle("crazyflie21_brushless_pwm")
    rpm_off, pwm_off, response = [], [], []
    for f in CF_FLIGHTS:
        src = DATA / "brushless_flights" / "data" / f
        rpm, pwm = read_log(src, rpm_v), read_log(src, pwm_v)
        rpm_off.append(align.offsets(rpm, rpm_v)["rotors"]["offset_s"])
        pwm_off.append(align.offsets(pwm, pwm_v)["rotors"]["offset_s"])
        speeds = [f"u{i}" for i in range(1, 5)]
        response.append(align._lag(rpm["t"].to_numpy(), pwm[speeds].to_numpy() ** 2, rpm[speeds].to_numpy() ** 2,
                                   align.MAX_LAG_S)[0])
    rpm_off, pwm_off, response = map(np.array, (rpm_off, pwm_off, response))
    assert np.abs(rpm_off - np.median(rpm_off)).max() < 0.005
    assert response.max() < -0.02  # the PWM leads the rpm by the motors' response (tens of ms)
    assert pwm_off - rpm_off == pytest.approx(response, abs=0.005)


def test_a_log_shorter_than_the_lag_window_gets_no_offset_and_no_error(flight):
    """0.8 s of data against a ±0.5 s lag window: nothing to compare, so nothing is said (not a traceback)."""
    short = flight[flight["t"] < flight["t"].iloc[0] + 0.8].reset_index(drop=True)
    assert align.offsets(short, load_vehicle(HB)) == {}
    assert set(align.offsets(flight.iloc[:1000], load_vehicle(HB))) == {"gyro", "rotors"}  # 10 s: both
