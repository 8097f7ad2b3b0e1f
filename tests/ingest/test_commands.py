"""Motor commands instead of rotor speeds (``rotor_input: command``): the command -> thrust map, the vehicle
file's checks, and a synthetic flight logged as commands (a CSV, and a PX4 ULog without ESC telemetry),
ingested and diagnosed as from its speeds."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import yaml

from conftest import DATA, VEHICLES, run_cli
from qr.errors import QrInputError
from qr.rotors import CommandMap
from qr.vehicle import load_vehicle, vehicle_from_dict
from ulog_writer import write_ulog

HB = VEHICLES / "asctec_hummingbird.yaml"


def test_the_command_map_by_hand():
    m = CommandMap(np.full(4, 0.1), np.full(4, 2.0), np.full(4, 6.0))
    c = np.array([[0.5, 0.0, 1.0, 0.25]])
    assert m.thrust(c)[0] == pytest.approx([0.1 + 1.0 + 1.5, 0.1, 0.1 + 2 + 6, 0.1 + 0.5 + 0.375])
    assert m.equivalent_speeds(c, 1e-5)[0, 0] == pytest.approx(np.sqrt(2.6 / 1e-5))
    with_battery = CommandMap(m.a, m.b, m.k, v_ref=16.0)  # 12 V of 16: the command acts as 0.75 of itself
    assert with_battery.thrust(np.array([[0.5] * 4]), np.array([12.0]))[0, 0] == pytest.approx(
        0.1 + 2 * 0.375 + 6 * 0.375**2)


def _vehicle_raw(**changes):
    raw = yaml.safe_load(HB.read_text())
    raw.update(changes)
    return raw


@pytest.mark.parametrize("changes, phrase", [
    ({"rotor_input": "command"}, "command_map (with b and k) is missing"),
    ({"rotor_input": "command", "command_map": {"b": 1.0, "k": -2.0}}, "does not rise with the command"),
    ({"rotor_input": "command", "command_map": {"b": 1.0, "k": 1.0, "gain": 2}}, "unknown key(s) ['gain']"),
    ({"rotor_input": "commands"}, "rotor_input is 'commands'"),
])
def test_a_command_vehicle_without_a_usable_map_is_one_line(changes, phrase):
    with pytest.raises(QrInputError, match=None) as e:
        vehicle_from_dict(_vehicle_raw(**changes), "v.yaml")
    assert phrase in str(e.value) and "\n" not in str(e.value)


def _commands(speeds: np.ndarray, vehicle, m: CommandMap) -> np.ndarray:
    """The commands whose thrust ``a + b c + k c²`` equals ``C_T u²`` (the positive root)."""
    F = vehicle.thrust_coeff * speeds**2
    return (-m.b + np.sqrt(m.b**2 - 4 * m.k * (m.a - F))) / (2 * m.k)


@pytest.mark.slow
def test_a_flight_logged_as_commands_diagnoses_as_from_its_rotor_speeds_also_from_a_px4_log(tmp_path, capsys):
    hb = load_vehicle(HB)
    assert run_cli(["synth", "--vehicle", HB, "--effect", "linear_drag:kx=0.3,ky=0.3,kz=0.15", "--duration", "60",
                    "--seed", "6", "--out", tmp_path / "synth"], capsys)[0] == 0
    speeds = pd.read_csv(tmp_path / "synth" / "flight.csv")
    f_max = hb.thrust_coeff * (1.8 * hb.hover_speed) ** 2  # full command: 1.8 x the hover speed
    amap = {"a": 0.0, "b": 0.3 * f_max, "k": 0.7 * f_max}
    m = CommandMap(*(np.full(4, amap[x]) for x in "abk"))
    logged = speeds.copy()
    logged[["u1", "u2", "u3", "u4"]] = _commands(speeds[["u1", "u2", "u3", "u4"]].to_numpy(), hb, m)
    assert logged[["u1", "u2", "u3", "u4"]].to_numpy().max() < 1
    logged.to_csv(tmp_path / "commands.csv", index=False)
    docs = {}
    for name, scale in (("right", 1.0), ("low", 0.96)):  # the map as identified, and one 4 % low
        vfile = tmp_path / f"{name}.yaml"
        vfile.write_text(yaml.safe_dump(_vehicle_raw(rotor_input="command",
                                                     command_map={k: v * scale for k, v in amap.items()})))
        out = tmp_path / f"{name}.parquet"
        status, _, err = run_cli(["ingest", tmp_path / "commands.csv", "--vehicle", vfile, "--out", out], capsys)
        assert status == 0, err
        if name == "right":  # the equivalent speeds are the speeds the commands were made from
            got = pd.read_parquet(out)[["u1", "u2", "u3", "u4"]].to_numpy()
            assert got == pytest.approx(speeds[["u1", "u2", "u3", "u4"]].to_numpy(), rel=1e-9)
        status, _, err = run_cli(["diagnose", out, "--vehicle", vfile, "--out", tmp_path / f"d_{name}"], capsys)
        assert status == 0, err
        docs[name] = json.loads((tmp_path / f"d_{name}" / "diagnosis.json").read_text())
    drag = next(e for e in docs["right"]["effects"] if e["name"] == "linear_drag")
    assert drag["parameters"]["kx"] == pytest.approx(0.3, rel=0.1)
    # a 4 % low map under-reads every rotor's thrust by 4 %: a C_T (thrust_gain) error of 1 / 0.96
    named = {e["name"]: e for e in docs["low"]["effects"]}
    assert "linear_drag" in named
    assert "thrust_gain" in named, list(named)
    assert named["thrust_gain"]["parameters"]["gain"] == pytest.approx(1 / 0.96, abs=0.01)
    # the same commands as a PX4 without ESC telemetry logs them (ULog: NED/FRD, float32, actuator_motors)
    write_ulog(tmp_path / "px4.ulg", logged["t"].to_numpy(), logged[["px", "py", "pz"]].to_numpy(),
               logged[["qw", "qx", "qy", "qz"]].to_numpy(), logged[["u1", "u2", "u3", "u4"]].to_numpy())
    status, _, err = run_cli(["ingest", tmp_path / "px4.ulg", "--vehicle", tmp_path / "right.yaml", "--out",
                              tmp_path / "px4.parquet"], capsys)
    assert status == 0, err
    status, _, err = run_cli(["diagnose", tmp_path / "px4.parquet", "--vehicle", tmp_path / "right.yaml", "--out",
                              tmp_path / "d_px4"], capsys)
    assert status == 0, err
    px4 = {e["name"]: e for e in json.loads((tmp_path / "d_px4" / "diagnosis.json").read_text())["effects"]}
    assert list(px4) == [e["name"] for e in docs["right"]["effects"]]
    for k, v in drag["parameters"].items():  # float32 storage: the same drag to a fraction of its s.e.
        assert px4["linear_drag"]["parameters"][k] == pytest.approx(v, abs=0.5 * drag["stderr"][k])
    # raw commands given straight to the diagnosis are refused with the way forward
    status, _, err = run_cli(["diagnose", tmp_path / "commands.csv", "--vehicle", tmp_path / "right.yaml", "--out",
                              tmp_path / "d_raw"], capsys)
    assert status == 2 and "look like motor commands" in err and "qr ingest" in err


@pytest.mark.slow
@pytest.mark.skipif(not (DATA / "brushless_flights").exists(), reason="measured Crazyflie data not present")
def test_the_crazyflie_diagnosed_from_its_pwm_tells_the_story_of_its_rpm(tmp_path, capsys):
    """The brushless logs carry both the RPM deck's speeds and the PWM commands. Six flights diagnosed
    each way (the source's PWM -> thrust fit, conf/vehicle/crazyflie21_brushless_pwm.yaml) name the same
    rotor drag, to 15 %, judge a roll-inertia error alike (the slow torque balance proposes one; the
    held-out part supports it in both or in neither), and both name blade flapping (5.3 against 6.8e-4
    N m s/m when written); the commands add what the speeds do not see: the motors' response, an actuator
    delay of tens of milliseconds. (How the thrust offset is split, C_T against a constant force, differs:
    the two calibrations differ by 3 % at hover.)"""
    flights = ["eckart00", "eckart01", "eckart02", "eckart03", "eckart04", "eckart06"]
    docs = {}
    for v in ("crazyflie21_brushless", "crazyflie21_brushless_pwm"):
        (tmp_path / v).mkdir()
        for f in flights:
            status, _, err = run_cli(["ingest", DATA / "brushless_flights" / "data" / f, "--vehicle", v, "--out",
                                      tmp_path / v / f"{f}.parquet"], capsys)
            assert status == 0, err
        status, _, err = run_cli(["diagnose", *[tmp_path / v / f"{f}.parquet" for f in flights], "--vehicle", v,
                                  "--out", tmp_path / f"d_{v}", "+experiment=[crazyflie_short_flights]"], capsys)
        assert status == 0, err
        doc = json.loads((tmp_path / f"d_{v}" / "diagnosis.json").read_text())
        docs[v] = {e["name"]: e["parameters"] for e in doc["effects"]}
    rpm, pwm = docs["crazyflie21_brushless"], docs["crazyflie21_brushless_pwm"]
    assert pwm["rotor_drag"]["k"] == pytest.approx(rpm["rotor_drag"]["k"], rel=0.15), (rpm, pwm)
    assert ("inertia_error" in rpm) == ("inertia_error" in pwm), (rpm, pwm)
    if "inertia_error" in rpm:
        assert pwm["inertia_error"]["dJxx"] == pytest.approx(rpm["inertia_error"]["dJxx"], rel=0.15)
    assert "blade_flapping" in rpm and "blade_flapping" in pwm
    assert "actuator_delay" not in rpm
    assert 0.02 <= pwm["actuator_delay"]["delay_s"] <= 0.08
