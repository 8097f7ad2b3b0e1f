"""Convention mistakes are caught before any identification, never diagnosed (qr.conventions).

Each mistake of the issue is made on a synthetic flight whose truth is a linear drag alone, and each
is refused by ``qr diagnose`` (and by ``qr evaluate`` and ``qr ingest``) in one line that names it and
its fix, nothing written.  The same flights as written pass, and so do every shipped vehicle's correct
synthetic flights and measured Crazyflie flights of every kind.  The mistakes are written here from
the spec's definitions (docs/spec/flight-log.md), independently of the readings qr tries back.
"""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest
import yaml
from scipy.spatial.transform import Rotation

from conftest import DATA, VEHICLES, run_cli
from qr import conventions
from qr.flight import read_flight
from qr.sim.synth import SynthConfig, write_synth
from qr.vehicle import load_vehicle

DRAG = [{"name": "linear_drag", "parameters": {"kx": 0.3, "ky": 0.3, "kz": 0.15}}]


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """A 40 s Hummingbird flight with a linear drag, and its truth (for a logged gyro)."""
    d = tmp_path_factory.mktemp("conv")
    write_synth(d / "s", load_vehicle(VEHICLES / "asctec_hummingbird.yaml"), DRAG, SynthConfig(duration=40, seed=3))
    df = pd.read_csv(d / "s" / "flight.csv")
    truth = pd.read_parquet(d / "s" / "truth.parquet")
    rng = np.random.default_rng(0)
    df[["gx", "gy", "gz"]] = truth[["wx", "wy", "wz"]].to_numpy() + rng.normal(0, 0.01, (len(df), 3))
    return d, df


def _ned_frd(df):
    """PX4's frames: NED position (north = ENU y, east = ENU x, down = -z), FRD body -> NED attitude."""
    out = df.copy()
    out["px"], out["py"], out["pz"] = df["py"], df["px"], -df["pz"]
    q = df[["qw", "qx", "qy", "qz"]].to_numpy()
    ok = np.isfinite(q).all(axis=1)
    enu_ned = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    flu_frd = np.diag([1.0, -1, -1])
    R = Rotation.from_quat(q[ok], scalar_first=True).as_matrix()
    qn = np.full_like(q, np.nan)
    qn[ok] = Rotation.from_matrix(enu_ned @ R @ flu_frd).as_quat(scalar_first=True)
    out[["qw", "qx", "qy", "qz"]] = qn
    return out


def _swapped(df, a, b):
    out = df.copy()
    out[[a, b]] = df[[b, a]].to_numpy()
    return out


MISTAKES = {  # the list: how the log was written -> the hint the refusal must carry
    "scalar_last": (lambda df: df.assign(qw=df.qx, qx=df.qy, qy=df.qz, qz=df.qw), "scalar-last"),
    "z_down": (lambda df: df.assign(pz=-df.pz), "z down"),
    "ned_frd": (_ned_frd, "NED world with an FRD body"),
    "conjugate": (lambda df: df.assign(qx=-df.qx, qy=-df.qy, qz=-df.qz), "world -> body"),
    "millimetres": (lambda df: df.assign(px=1000 * df.px, py=1000 * df.py, pz=1000 * df.pz), "millimetres"),
    "rotors_2_4": (lambda df: _swapped(df, "u2", "u4"), "the layout's rotors 1..4 are the log's u1, u4, u3, u2"),
    "gyro_frd": (lambda df: df.assign(gy=-df.gy, gz=-df.gz), "the gyro looks FRD"),
    "gyro_degrees": (lambda df: df.assign(gx=np.degrees(df.gx), gy=np.degrees(df.gy), gz=np.degrees(df.gz)),
                     "degrees per second"),
}


@pytest.mark.parametrize("mistake", list(MISTAKES))
def test_each_mistake_is_refused_by_qr_diagnose_with_its_hint(flight, mistake, tmp_path, capsys):
    d, df = flight
    make, hint = MISTAKES[mistake]
    f = tmp_path / "flight.csv"
    make(df).to_csv(f, index=False)
    status, _, err = run_cli(["diagnose", f, "--vehicle", d / "s" / "vehicle.yaml", "--out", tmp_path / "out"], capsys)
    assert status == 2, err
    (line,) = err.strip().splitlines()
    assert str(f) in line and hint in line and "fix: " in line and "skip_checks=[" in line, line
    assert not (tmp_path / "out").exists()


def test_the_flight_as_written_passes_every_check(flight):
    d, df = flight
    results = conventions.check(df, load_vehicle(d / "s" / "vehicle.yaml"))
    assert [r.name for r in results] == list(conventions.CHECKS)
    assert all(r.passed for r in results), results


def test_qr_evaluate_and_qr_ingest_refuse_a_mistake_too(flight, tmp_path, capsys):
    d, df = flight
    f = tmp_path / "flight.csv"
    MISTAKES["z_down"][0](df).to_csv(f, index=False)
    v = d / "s" / "vehicle.yaml"
    status, _, err = run_cli(["evaluate", f, "--vehicle", v, "--out", tmp_path / "ev"], capsys)
    assert status == 2 and "z down" in err and "evaluate.skip_checks=[thrust_axis]" in err, err
    status, _, err = run_cli(["ingest", f, "--vehicle", v, "--out", tmp_path / "in.csv"], capsys)
    assert status == 2 and "z down" in err and "--skip-check thrust_axis" in err, err
    assert not (tmp_path / "in.csv").exists() and not (tmp_path / "ev").exists()


def test_a_skipped_check_lets_a_user_who_knows_better_through(flight, tmp_path, capsys):
    """The skip is honoured; and a log the model then cannot describe is said so, nothing named."""
    import json

    d, df = flight
    f = tmp_path / "flight.csv"
    MISTAKES["scalar_last"][0](df).to_csv(f, index=False)
    status, _, err = run_cli(["diagnose", f, "--vehicle", d / "s" / "vehicle.yaml", "--out", tmp_path / "out",
                              "diagnose.skip_checks=[thrust_axis,gyro,rotor_layout]"], capsys)
    assert status == 0, err
    doc = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert doc["effects"] == [] and doc["described"] is False
    assert doc["misfit"]["force_of_weight"] > doc["misfit"]["limit"]
    assert doc["verdict"].startswith("The model does not describe this flight")
    assert not yaml.safe_load((tmp_path / "out" / "extended_vehicle.yaml").read_text()).get("effects")
    status, _, err = run_cli(["ingest", f, "--vehicle", d / "s" / "vehicle.yaml", "--out", tmp_path / "x.csv",
                              "--skip-check", "nonsense"], capsys)
    assert status == 2 and "unknown convention check 'nonsense'" in err


def _file(d, tmp_path, **changes):
    raw = yaml.safe_load((d / "s" / "vehicle.yaml").read_text())
    path = tmp_path / "vehicle.yaml"
    path.write_text(yaml.safe_dump({**raw, **changes}))
    return path


def test_a_plus_frame_flight_with_an_x_file_is_refused_naming_the_plus_layout(flight, tmp_path, capsys):
    """The issue's case: layout x (and the mass 14 % off) for a plus-frame flight.  Rotated 45°, the x map's
    roll and pitch torques still correlate with the needed ones (cos 45° of them): only a comparison with
    the plus layout's tells; refused in one line with the layout that fits and the fix."""
    d, df = flight
    f = tmp_path / "flight.csv"
    df.to_csv(f, index=False)
    wrong = _file(d, tmp_path, layout="x", mass=0.8)
    status, _, err = run_cli(["diagnose", f, "--vehicle", wrong, "--out", tmp_path / "out"], capsys)
    assert status == 2, err
    (line,) = err.strip().splitlines()
    assert str(f) in line and "look like layout plus, not the vehicle file's layout (x)" in line, line
    assert "fix: write layout: plus in the vehicle file" in line and "skip_checks=[rotor_layout]" in line, line
    m = re.search(r"is ([-\d.]+), ([-\d.]+), ([-\d.]+) in roll.*best other reading, layout plus, gives ([-\d.]+), "
                  r"([-\d.]+), ([-\d.]+) \(summed \+([\d.]+)", line)
    x_file, plus = np.array(m.groups()[:3], float), np.array(m.groups()[3:6], float)
    assert plus.sum() - x_file.sum() == pytest.approx(float(m[7]), abs=0.015) and plus[:2].min() > x_file[:2].min()
    assert not (tmp_path / "out").exists()
    right = conventions.check(df, load_vehicle(_file(d, tmp_path, mass=0.8)))[-1]
    assert right.passed and "the best other reading, layout x, gives" in right.measured, right.measured
    assert right.measured.endswith(": the file's layout fits"), right.measured


def test_a_rotor_numbering_is_said_the_way_round_the_log_has_it(flight):
    """Rotors 1, 2, 3 of the file logged as u2, u3, u1 (a cycle: the numbering and its inverse differ)."""
    d, df = flight
    cycled = df.copy()
    cycled[["u2", "u3", "u1"]] = df[["u1", "u2", "u3"]].to_numpy()
    (r,) = conventions.check(cycled, load_vehicle(d / "s" / "vehicle.yaml"), skip=("thrust_axis", "gyro"))
    assert not r.passed and r.mistake.endswith("the layout's rotors 1..4 are the log's u2, u3, u1, u4"), r.mistake
    back = cycled[["u2", "u3", "u1", "u4"]].to_numpy()  # the hint read literally puts them back
    assert np.array_equal(back, df[["u1", "u2", "u3", "u4"]].to_numpy(), equal_nan=True)


@pytest.mark.parametrize("name", sorted(p.stem for p in VEHICLES.glob("*.yaml")))
def test_every_shipped_vehicles_correct_flight_passes(name, tmp_path):
    vehicle = load_vehicle(VEHICLES / f"{name}.yaml")
    write_synth(tmp_path / "s", vehicle, [], SynthConfig(duration=30, seed=11))
    results = conventions.check(read_flight(tmp_path / "s" / "flight.csv"), vehicle)
    assert all(r.passed for r in results), results


@pytest.mark.skipif(not DATA.exists(), reason="measured data not available")
@pytest.mark.parametrize("folder, flight, vehicle", [
    ("brushless_flights", "eckart00", "crazyflie21_brushless"),
    ("brushless_flights", "eckart27", "crazyflie21_brushless"),  # the fastest figure-8s
    ("brushless_flights", "eckart06", "crazyflie21_brushless_pwm"),  # through the PWM command map
    ("brushless_flights_payload", "eckart06", "crazyflie21_brushless_payload"),
    ("brushless_flights_payload", "eckart67", "crazyflie21_brushless_payload"),
])
def test_measured_crazyflie_flights_pass(folder, flight, vehicle):
    from qr.ingest import read_log

    v = load_vehicle(VEHICLES / f"{vehicle}.yaml")
    results = conventions.check(read_log(DATA / folder / "data" / flight, v), v)
    assert all(r.passed for r in results), results
