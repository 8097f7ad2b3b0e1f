"""`qr diagnose` finds what was hidden: every catalog effect alone, combinations, and nothing in null flights.

Each case flies a 90 s, 100 Hz synthetic flight with realistic noise (mocap
0.5 mm / 0.17°, rotor speeds 0.5 % of hover, 0.5 % dropouts) and runs the
user-facing `run_diagnosis` on its CSV.  The noise floor of the issue is the
RMSE of the TRUE-effect model on the same filtered data (held-out part).
"""

import json

import numpy as np
import pytest
import yaml

from conftest import VEHICLES
from decisions import assert_same_decisions, diagnose_elsewhere
from qr.stages.diagnose import run_diagnosis
from qr.diagnose.core import rms
from qr.effects import CATALOG, parse_effect_spec, total_term
from qr.sim.scenarios import EXAMPLES
from qr.sim.synth import NoiseConfig, SynthConfig, write_synth
from qr.sim.trajectory import TrajectoryConfig
from qr.vehicle import load_vehicle

SINGLE = EXAMPLES  # the catalog's example sizes (qr.sim.scenarios: the one place)
COMBOS = [
    ("linear_drag", "cg_offset"),
    ("wind_force", "yaw_torque_gain", "blade_flapping"),
    ("thrust_gain", "ground_effect"),
    # the closed loop cancels blade flapping's torque with rotor torque: until flapping is named, the
    # torque rows contradict the force rows on C_T (the measured brushless Crazyflie flights)
    ("thrust_gain", "blade_flapping"),
    # issue 13's torque-side candidates, each beside flapping and a C_T error (the measured pair)
    ("inertia_error", "blade_flapping", "thrust_gain"),
    ("yaw_torque_gain", "blade_flapping", "thrust_gain"),
]
# the hub effects beside the effects they could be mistaken for: one rotor drag's force and moment (one k), a
# C_Q error, a C_T error, a constant world force
HUB_COMBOS = [
    ("rotor_drag", "rotor_drag_moment"),
    ("rotor_drag_moment", "yaw_torque_gain"),
    ("rotor_drag_moment", "thrust_gain"),
    ("rotor_drag_moment", "wind_force"),
    ("translational_lift", "rotor_drag"),
    ("translational_lift", "yaw_torque_gain"),
    ("translational_lift", "thrust_gain"),
    ("translational_lift", "wind_force"),
    ("rotor_drag", "rotor_drag_moment", "translational_lift"),
]
NOISE_LEVELS = {"low": NoiseConfig(position_std=0.0003, attitude_std=0.002, rotor_std=0.003),
                "default": NoiseConfig(),
                "high": NoiseConfig(position_std=0.001, attitude_std=0.005, rotor_std=0.01, dropout=0.01)}
NULLS = [(seed, level) for level in NOISE_LEVELS for seed in range(21, 26)]


def _synth(tmp_path, names, seed=7, noise=None, duration=90):
    """A 90 s, 100 Hz Hummingbird flight with ``names`` hidden, in ``tmp_path / "s"``; its effects."""
    vehicle = load_vehicle(VEHICLES / "asctec_hummingbird.yaml")
    effects = [parse_effect_spec(n if ":" in n else f"{n}:{SINGLE[n]}") for n in names]
    traj = TrajectoryConfig(low_passes=any(e["name"] == "ground_effect" for e in effects))
    write_synth(tmp_path / "s", vehicle, effects, SynthConfig(duration=duration, rate=100, seed=seed,
                                                             noise=noise or NoiseConfig(), trajectory=traj))
    return vehicle, effects


def _case(tmp_path, names, seed=7, noise=None, figures=False, duration=90):
    """Synthesise, then diagnose; figures only where a test looks at them (they are a third of the time)."""
    vehicle, effects = _synth(tmp_path, names, seed, noise, duration)
    doc, res = run_diagnosis([tmp_path / "s" / "flight.csv"], tmp_path / "s" / "vehicle.yaml", tmp_path / "d",
                             log=lambda m: None, return_result=True, figures=figures)
    prep = res.labels.full
    floor = rms((prep.y - total_term(effects, prep.s, vehicle))[prep.test])
    return effects, doc, floor


def _check_extended(doc, effects, floor):
    ext = np.array(doc["extended"]["force_rmse"] + doc["extended"]["torque_rmse"])
    axes = sorted({a for e in effects for a in CATALOG[e["name"]].axes})
    for a in axes:
        assert ext[a] <= 1.25 * floor[a], (a, ext[a], floor[a])


# hidden effects whose decision is also repeated on another machine's arithmetic (tests/decisions.py): the
# delay (a 1-D search), a C_T error (arbitrated by the torque rows), a marker offset, an inertia error
ELSEWHERE = ("actuator_delay", "thrust_gain", "marker_offset", "inertia_error")


@pytest.mark.parametrize("name", sorted(SINGLE))
def test_single_effect_is_found(name, tmp_path):
    effects, doc, floor = _case(tmp_path, [name])
    named = [e["name"] for e in doc["effects"]]
    assert named == [name], doc["selection"]
    if name in ELSEWHERE:
        s = tmp_path / "s"
        assert_same_decisions(doc, diagnose_elsewhere([s / "flight.csv"], s / "vehicle.yaml", tmp_path / "there",
                                                      case=ELSEWHERE.index(name)))
    eff = CATALOG[name]
    for (k, true), neutral in zip(effects[0]["parameters"].items(), eff.neutral):
        got = doc["effects"][0]["parameters"][k]
        # 20 % of the effect's size: a gain's size is its distance from the neutral 1
        assert abs(got - true) <= 0.2 * abs(true - neutral), (k, got, true)
    _check_extended(doc, effects, floor)
    nominal, extended = doc["replay"]["nominal_position_rmse"], doc["replay"]["extended_position_rmse"]
    if name == "marker_offset":  # a kinematic effect: the dynamics, hence the drift, are the same
        assert extended == pytest.approx(nominal, rel=0.1)
    elif set(CATALOG[name].axes) & {0, 1, 2}:  # a force acts on the position directly
        assert extended <= nominal
    # (a torque effect reaches the position only through the attitude, whose open-loop drift over
    # the horizon is dominated by noise in the initial rates; its replay is reported, not asserted)


@pytest.mark.parametrize("names", COMBOS, ids=["+".join(c) for c in COMBOS])
def test_combinations_are_found_without_extras(names, tmp_path):
    effects, doc, floor = _case(tmp_path, list(names), seed=8)
    assert sorted(e["name"] for e in doc["effects"]) == sorted(names), doc["selection"]
    _check_extended(doc, effects, floor)


@pytest.mark.parametrize("names", HUB_COMBOS, ids=["+".join(c) for c in HUB_COMBOS])
def test_hub_effects_in_combinations_are_named_with_their_parameters(names, tmp_path):
    """Exactly the hidden set, every parameter within 20 % of its size; rotor_drag and rotor_drag_moment
    named together with one k (the spec); no vehicle-file statement (none is wrong here).  Two of them
    (the tied pair, the damping beside a C_Q error) decided again on another machine's arithmetic."""
    effects, doc, floor = _case(tmp_path, list(names), seed=8, duration=60)
    named = {e["name"]: e["parameters"] for e in doc["effects"]}
    assert sorted(named) == sorted(names), doc["selection"]
    for e in effects:
        for (k, true), neutral in zip(e["parameters"].items(), CATALOG[e["name"]].neutral):
            assert abs(named[e["name"]][k] - true) <= 0.2 * abs(true - neutral), (e["name"], k, named[e["name"]][k])
    if {"rotor_drag", "rotor_drag_moment"} <= set(named):
        assert named["rotor_drag"] == named["rotor_drag_moment"]
    assert not doc["vehicle_file"]
    _check_extended(doc, effects, floor)
    if names in HUB_COMBOS[:2]:
        s = tmp_path / "s"
        assert_same_decisions(doc, diagnose_elsewhere([s / "flight.csv"], s / "vehicle.yaml", tmp_path / "there",
                                                      case=HUB_COMBOS.index(names)))


def test_a_yaw_torque_that_grows_with_the_yaw_rate_is_no_c_q_statement(tmp_path):
    """A strong rotor drag moment (J_zz / (k Σu Σr²) ≈ 0.45 s): named as rotor_drag_moment, no C_Q error and
    nothing about the file.  With rotor_drag_moment excluded, the closed loop's yaw torque reads as a C_Q
    gain of ~0.13, "x7.7 too large" by the file's numbers: not stated, because a yaw-rate damping fitted
    beside it takes the factor (the rule of docs/spec/diagnosis.md), and the report says why."""
    effects, doc, _ = _case(tmp_path, ["rotor_drag_moment:k=4e-5"], seed=7, duration=60)
    assert [e["name"] for e in doc["effects"]] == ["rotor_drag_moment"], doc["selection"]
    assert doc["effects"][0]["parameters"]["k"] == pytest.approx(4e-5, rel=0.2)
    assert not doc["vehicle_file"] and not doc["vehicle_file_unresolved"]
    s = tmp_path / "s"
    assert_same_decisions(doc, diagnose_elsewhere([s / "flight.csv"], s / "vehicle.yaml", tmp_path / "there", case=2))
    doc = run_diagnosis([s / "flight.csv"], s / "vehicle.yaml", tmp_path / "d2", ["diagnose.exclude=[rotor_drag_moment]"],
                        log=lambda m: None, figures=False)
    named = {e["name"]: e["parameters"] for e in doc["effects"]}
    assert named["yaw_torque_gain"]["gain"] <= 1 / 1.5  # a gross factor by the file's numbers ...
    assert not doc["vehicle_file"] and "C_Q" not in doc["verdict"]  # ... never said
    (why,) = [u["why"] for u in doc["vehicle_file_unresolved"] if u["key"] == "torque_coeff"]
    assert "yaw-rate damping" in why and "grows with the yaw rate" in why


@pytest.mark.parametrize("seed, level", NULLS, ids=[f"{lv}-seed{s}" for s, lv in NULLS])
def test_null_flights_name_nothing_and_sit_at_the_noise_floor(seed, level, tmp_path):
    """Nothing hidden (60 s flights, 5 seeds x 3 noise levels): nothing named, and the noise floor means
    what it says: the held-out residual, weighted by the floor's inverse variance, averages 1 (the
    issue's band [0.8, 1.25]); a floor over-estimated 1.2-1.9x gave 0.3-0.7 here."""
    _, doc, res = _case_res(tmp_path, seed, NOISE_LEVELS[level])
    assert doc["effects"] == []
    assert doc["verdict"].startswith("Nothing named: the nominal model explains this flight up to noise")
    assert 0.8 <= res.held_out.nominal_loss <= 1.25, res.held_out.nominal_loss


def _case_res(tmp_path, seed, noise):
    vehicle, effects = _synth(tmp_path, [], seed, noise, duration=60)
    doc, res = run_diagnosis([tmp_path / "s" / "flight.csv"], tmp_path / "s" / "vehicle.yaml", tmp_path / "d",
                             log=lambda m: None, return_result=True, figures=False)
    return effects, doc, res


def test_contract_and_outputs(tmp_path):
    effects, doc, _ = _case(tmp_path, ["linear_drag", "cg_offset"], seed=3, figures=True)
    out = tmp_path / "d"
    assert sorted(p.name for p in out.iterdir()) == [".qr-output.json", "diagnosis.json", "extended_vehicle.yaml",
                                                     "figures", "report.md"]
    on_disk = json.loads((out / "diagnosis.json").read_text())
    assert on_disk["schema"] == "qr.diagnosis/1" and on_disk["flights"] == [str(tmp_path / "s" / "flight.csv")]
    assert on_disk["samples"] > 8000
    tr, te = on_disk["split"]["train"], on_disk["split"]["test"]
    # in the flight file's time (it starts at t = 0): from the first sample used (after trim_s = 0.5 s) to
    # the last, gap_s = 1 s between
    assert tr[0] == 0.5 and te[0] - tr[1] == pytest.approx(1.0) and te[1] == 89.5
    for key in ("nominal", "extended"):
        assert len(on_disk[key]["force_rmse"]) == 3 and len(on_disk[key]["torque_rmse"]) == 3
    for e in on_disk["effects"]:
        assert set(e) >= {"name", "parameters", "stderr", "explained_fraction", "confounded_with"}
        assert set(e["parameters"]) == set(e["stderr"]) == set(CATALOG[e["name"]].params)
    assert set(on_disk["replay"]) >= {"horizon_s", "nominal_position_rmse", "extended_position_rmse"}
    assert on_disk["replay"]["extended_position_rmse"] < 0.2 * on_disk["replay"]["nominal_position_rmse"]
    ext = yaml.safe_load((out / "extended_vehicle.yaml").read_text())
    assert [e["name"] for e in ext["effects"]] == [e["name"] for e in on_disk["effects"]]
    assert load_vehicle(out / "extended_vehicle.yaml").mass == 0.7
    report = (out / "report.md").read_text()
    for fig in ("residual_vs_effects.png", "replay_drift.png", "residual_anatomy.png"):
        assert f"figures/{fig}" in report and (out / "figures" / fig).stat().st_size > 5000


def test_extended_vehicle_feeds_back_into_a_second_diagnosis(tmp_path):
    """Diagnosing again with the extended vehicle finds nothing more (the carry-over the workflow uses)."""
    _case(tmp_path, ["wind_force"], seed=4)
    doc = run_diagnosis([tmp_path / "s" / "flight.csv"], tmp_path / "d" / "extended_vehicle.yaml", tmp_path / "d2",
                        log=lambda m: None, figures=False)
    assert doc["effects"] == []


def test_a_vehicle_file_with_another_airframe_s_inertia_is_named_with_a_c_t_error_beside_it(tmp_path):
    """The Crazyflie brushless situation (its file quotes another airframe's inertia): a C_T error of
    +8 % hidden, and the diagnosis vehicle states a fifth of the true inertia.  J α then reads
    1.08/5 = 0.216 of the rotor-map torque in roll and pitch: an inertia error, not a C_T error of 0.2.
    The file's inertia is named x5 too small on every axis, and the C_T error beside it (confounded
    with a mass error in force: the torque rows cannot tell them apart once the inertia is free)."""
    _synth(tmp_path, ["thrust_gain"], seed=5)
    raw = yaml.safe_load((tmp_path / "s" / "vehicle.yaml").read_text())
    raw["inertia"] = [j / 5 for j in raw["inertia"]]
    (tmp_path / "fifth.yaml").write_text(yaml.safe_dump(raw))
    doc = run_diagnosis([tmp_path / "s" / "flight.csv"], tmp_path / "fifth.yaml", tmp_path / "d5", log=lambda m: None,
                        figures=False)
    named = {e["name"]: e for e in doc["effects"]}
    assert sorted(named) == ["inertia_error", "thrust_gain"], doc["selection"]
    assert named["thrust_gain"]["parameters"]["gain"] == pytest.approx(1.08, abs=0.2 * 0.08)
    assert "mass_error" in named["thrust_gain"]["confounded_with"]
    factors = {c["key"]: c["factor"] for c in doc["vehicle_file"]}
    for i in range(3):
        assert factors[f"inertia[{i}]"] == pytest.approx(5.0, rel=0.1)
    assert "Jxx (inertia[0]) in " in doc["verdict"] and "looks x5 too small" in doc["verdict"]
    # without the inertia error among the candidates, the torque rows would need a C_T error of 0.216
    # (below the 1/3 bound): they cannot arbitrate C_T, which is fitted on the force rows, where it is
    # the same term as a mass error (the spec's rule, and the Crazyflie situation before)
    doc = run_diagnosis([tmp_path / "s" / "flight.csv"], tmp_path / "fifth.yaml", tmp_path / "d5x",
                        ["diagnose.exclude=[inertia_error,yaw_torque_gain]"], log=lambda m: None, figures=False)
    arb = doc["selection"]["torque_arbitration"]["thrust_gain"]
    assert arb["force_rows"][0] == pytest.approx(1.08, abs=0.2 * 0.08)
    assert 1.08 / 5 - 0.02 <= arb["torque_rows"][0] < 1 / 3
    named = {e["name"]: e for e in doc["effects"]}
    assert named["thrust_gain"]["parameters"]["gain"] == pytest.approx(1.08, abs=0.2 * 0.08)
    assert "mass_error" in named["thrust_gain"]["confounded_with"] and "mass_error" not in named


def test_a_c_q_ten_times_too_small_is_the_finding(tmp_path):
    """A null flight diagnosed with C_Q / 10 in the vehicle file: J_z α_z = 10 x the file's yaw torque,
    a yaw_torque_gain of 10, named with its value and a line for the file: about C_Q / J_zz, the ratio the
    yaw balance identifies."""
    _synth(tmp_path, [], seed=11, duration=60)
    raw = yaml.safe_load((tmp_path / "s" / "vehicle.yaml").read_text())
    raw["torque_coeff"] /= 10
    (tmp_path / "cq.yaml").write_text(yaml.safe_dump(raw))
    doc = run_diagnosis([tmp_path / "s" / "flight.csv"], tmp_path / "cq.yaml", tmp_path / "d", log=lambda m: None,
                        figures=False)
    assert [e["name"] for e in doc["effects"]] == ["yaw_torque_gain"]
    assert doc["effects"][0]["parameters"]["gain"] == pytest.approx(10.0, abs=0.2 * 9)
    (check,) = doc["vehicle_file"]
    assert check["key"] == "torque_coeff" and check["estimate"] == pytest.approx(8e-10, rel=0.2)
    assert f"C_Q / Jzz (torque_coeff / inertia[2]) in {tmp_path / 'cq.yaml'} looks x10 too small" in doc["verdict"]


def test_a_c_t_error_and_a_body_frame_side_force_are_told_apart(tmp_path):
    """A C_T error (force ∝ T along body z) plus a small constant body-frame x/y force.

    ``body_force_bias`` alone explains most of both (its bz stands in for the C_T error while T
    barely changes); the best pair names both, the body-frame force with its true x/y parts and no
    z part (the C_T error's, because T does vary).
    """
    effects, doc, floor = _case(tmp_path, ["thrust_gain", "body_force_bias:bx=0.06,by=-0.05,bz=0"], seed=6)
    named = {e["name"]: e["parameters"] for e in doc["effects"]}
    assert sorted(named) == ["body_force_bias", "thrust_gain"], doc["selection"]
    assert named["thrust_gain"]["gain"] == pytest.approx(1.08, abs=0.2 * 0.08)  # 20 % of the error
    assert named["body_force_bias"]["bx"] == pytest.approx(0.06, rel=0.2)
    assert named["body_force_bias"]["by"] == pytest.approx(-0.05, rel=0.2)
    hover_error = 0.08 * load_vehicle(tmp_path / "s" / "vehicle.yaml").mass * 9.81  # the C_T error's force
    assert abs(named["body_force_bias"]["bz"]) < 0.2 * hover_error
    _check_extended(doc, effects, floor)
