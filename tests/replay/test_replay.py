"""``qr replay`` (docs/spec/replay.md) on synthetic flights made under the same controller, the command line,
its refusals, and a measured Crazyflie flight."""

import json

import numpy as np
import pytest

from conftest import DATA, VEHICLES, run_cli

FIGURE8 = DATA.parent / "crazyswarm2-figure8" / "figure8.csv"
pytestmark = pytest.mark.skipif(not FIGURE8.exists(), reason="no figure-8 trajectory beside the data")
CF = VEHICLES / "crazyflie21_brushless.yaml"


def synth(tmp_path, name, capsys, *effects, timescale=0.6, noise_free=True):
    out = tmp_path / name
    args = ["synth", "--vehicle", CF, "--controller", "lee", "--trajectory", FIGURE8, "--timescale", timescale,
            "--seed", 1, "--out", out, *[a for e in effects for a in ("--effect", e)]]
    status, _, err = run_cli(args + (["--noise-free"] if noise_free else []), capsys)
    assert status == 0, err
    return out


def replay(tmp_path, name, flight, vehicles, capsys, *overrides):
    out = tmp_path / name
    args = ["replay", flight, *[a for v in vehicles for a in ("--vehicle", v)], "--controller", "lee", "--out", out,
            *overrides]
    status, _, err = run_cli(args, capsys)
    assert status == 0, err
    return json.loads((out / "replay.json").read_text()), out


def true_vehicle(folder, tmp_path):
    """The synthetic flight's TRUE vehicle file: its nominal vehicle.yaml plus the hidden effects."""
    import yaml

    raw = yaml.safe_load((folder / "vehicle.yaml").read_text())
    raw["effects"] = json.loads((folder / "truth.json").read_text())["effects"]
    path = tmp_path / f"{folder.name}_true.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def test_a_synthetic_flight_replayed_with_its_true_vehicle_comes_back_to_numerical_precision(tmp_path, capsys):
    """A flight qr synth made under the Lee controller (a hidden drag and CG offset), replayed with its true
    vehicle: the logged flight to the precision of its CSV (9 digits); with the nominal vehicle, centimetres."""
    s = synth(tmp_path, "s", capsys, "linear_drag:kx=0.02,ky=0.02,kz=0.01", "cg_offset:rx=0.001,ry=-0.001")
    doc, out = replay(tmp_path, "r", s / "flight.csv", [true_vehicle(s, tmp_path), s / "vehicle.yaml"], capsys)
    true, nominal = doc["models"].values()
    assert true["position"]["rmse_m"] < 1e-8 and true["attitude"]["rmse_deg"] < 1e-5, true
    assert true["rotor_speed"]["rmse_percent"] < 1e-6 and true["position"]["parts_at_s"] is None
    assert nominal["position"]["rmse_m"] > 1e-3 and nominal["rotor_speed"]["rmse_percent"] > 1e-3, nominal
    sp = next(iter(doc["setpoints"].values()))
    assert sp["source"] == "synth" and sp["timescale"] == 0.6 and sp["controller_mass_kg"] == pytest.approx(0.037)
    assert (out / "report.md").read_text().startswith("# qr replay\n\nFlown in closed loop under the lee controller")
    assert list((out / "figures").glob("*.png"))


def test_the_nominal_vehicles_error_grows_with_the_hidden_effects_size(tmp_path, capsys):
    """A hidden mass error dm, replayed with the nominal vehicle: the Lee controller (no position integral, the
    nominal mass) holds a steady height error dm g / (m Kp) that the nominal replay lacks: 3.79 cm per gram on
    the 37 g Crazyflie (Kp = 7 /s²).  The replay's RMSE grows with dm and its size is the hand-derived one."""
    errors = []
    for dm in (0.0, 0.001, 0.002):
        s = synth(tmp_path, f"s{dm}", capsys, f"mass_error:dm={dm}")
        doc, _ = replay(tmp_path, f"r{dm}", s / "flight.csv", [s / "vehicle.yaml"], capsys)
        errors.append(next(iter(doc["models"].values()))["position"]["rmse_m"])
    assert errors[0] < 1e-8 and errors[1] < errors[2], errors
    for dm, e in zip((0.001, 0.002), errors[1:]):
        steady = dm * 9.81 / (0.037 * 7.0)  # m; the error is this once settled (it starts at zero)
        assert 0.6 * steady < e < 1.05 * steady, (dm, e, steady)


@pytest.mark.parametrize("args, message", [
    (["--controller", "lee"], "carries no setpoints and no trajectory is given; fix: add replay.trajectory="),
    (["--controller", "pid"], "pid: unknown controller; fix: use --controller lee, rotorpy_se3 or MODULE:CLASS"),
    (["--controller", "no_such_module:X"], "controller class cannot be imported"),
    (["--controller", "lee", f"replay.trajectory={DATA}/nope.csv"], "nope.csv: trajectory file does not exist"),
    (["--controller", "lee", "replay.timescale=-1"], "replay.timescale: -1 is out of range"),
    (["--controller", "lee", "controller.KR=[1,2]"], "controller.KR: [1, 2] is not three non-negative numbers"),
    (["--controller", "lee", "replay.mixer=magic"], "replay.mixer: 'magic' is not one of auto, crazyflie, ideal"),
])
def test_bad_input_is_one_line_and_nothing_written(tmp_path, capsys, args, message):
    from conftest import small_flight
    from qr.flight import write_flight

    flight = tmp_path / "flight.csv"
    write_flight(small_flight(), flight)
    if "replay.trajectory" not in " ".join(args) and args[1] == "lee" and len(args) > 2:
        args = [*args, f"replay.trajectory={FIGURE8}"]
    status, _, err = run_cli(["replay", flight, "--vehicle", VEHICLES / "asctec_hummingbird.yaml", "--out",
                              tmp_path / "out", *args], capsys)
    assert status == 2 and message in err and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()


def test_a_flight_beside_the_trajectory_it_did_not_fly_is_refused(tmp_path, capsys):
    s = synth(tmp_path, "s", capsys, timescale=0.6)
    status, _, err = run_cli(["replay", s / "flight.csv", "--vehicle", s / "vehicle.yaml", "--controller", "lee",
                              "--out", tmp_path / "r", "replay.offset_s=100"], capsys)
    # a synth folder carries its setpoints: the override of the start time does not apply to it ...
    assert status == 0, err
    csv = tmp_path / "plain.csv"
    csv.write_bytes((s / "flight.csv").read_bytes())  # ... a flight without them takes it, and is refused
    status, _, err = run_cli(["replay", csv, "--vehicle", s / "vehicle.yaml", "--controller", "lee", "--out",
                              tmp_path / "r2", f"replay.trajectory={FIGURE8}", "replay.offset_s=100"], capsys)
    assert status == 2 and "does not overlap the trajectory" in err, err


@pytest.mark.skipif(not (DATA / "brushless_flights").is_dir(), reason="no IMRCLab data")
def test_a_measured_flight_finds_its_setpoints_from_the_motor_commands(tmp_path, capsys):
    """A brushless log (TIMESCALE 0.5, eckart30): from its PWM commands the replay finds the controller's
    mass parameter (the flight's 37 g), the start point (0, 0, 0.5 m, the mocap origin) and the start time to a
    few ms; the nominal vehicle then flies within decimetres of the log (the thrust map and drag it lacks)."""
    log = DATA / "brushless_flights" / "data" / "eckart30"
    doc, out = replay(tmp_path, "r", log, [CF], capsys, f"replay.trajectory={FIGURE8}", "replay.timescale=0.5")
    sp = doc["setpoints"][str(log)]
    assert sp["source"] == "commands" and sp["controller_mass_kg"] == pytest.approx(0.037, rel=0.01)
    assert np.allclose(sp["origin_m"], [0.0, 0.0, 0.5], atol=0.01) and sp["offset_uncertainty_s"] < 0.005
    assert sp["motor_map"]["kind"] == "fit" and sp["mixer"] == "crazyflie"
    m = doc["models"]["crazyflie21_brushless.yaml"]
    assert 0.01 < m["position"]["rmse_m"] < 0.2 and m["thrust"]["kind"] == "command", m
    assert m["diverged_at_s"] is None


def test_a_tracked_replay_logs_each_vehicles_errors_as_metrics(tmp_path, capsys, monkeypatch):
    """One MLflow run (experiment qr-replay) with, per vehicle label, the position, attitude, rotor-speed and
    thrust RMSE of replay.json, and the report's first sentence as its description."""
    monkeypatch.setenv("QR_TRACKING", "on")
    from qr import tracking
    from qr.stages.replay import run_replay

    s = synth(tmp_path, "s", capsys, "linear_drag:kx=0.02,ky=0.02,kz=0.01", timescale=0.5)
    doc = run_replay([s / "flight.csv"], [true_vehicle(s, tmp_path), s / "vehicle.yaml"], "lee", tmp_path / "r",
                     labels=["true", "nominal"], track="replay:test", log=lambda m: None)
    run = tracking._client().search_runs([tracking.experiment_id("replay")])[0]
    m = run.data.metrics
    assert m["nominal.position_rmse_m"] == pytest.approx(doc["models"]["vehicle.yaml"]["position"]["rmse_m"])
    assert m["true.position_rmse_m"] < 1e-8 and {"nominal.attitude_rmse_deg", "nominal.rotor_rmse_percent",
                                                   "nominal.thrust_rmse_N"} <= set(m)
    assert run.data.tags["mlflow.note.content"].startswith("Flown in closed loop")
