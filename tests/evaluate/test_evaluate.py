"""``qr evaluate`` and the rollout it computes (../shared/spec/evaluate.md).

Independent expectations: the reference ``hold``'s error is the measured motion itself (computed here
with numpy); the true model started from the true state reproduces a noise-free flight (errors
≈ the zero-order hold of the rotor speeds only); the rate-frozen baseline's body-rate error is the
hold's (ω held in both); dropouts and input gaps remove exactly the windows the spec says.
"""

import json
import subprocess
import sys

import numpy as np
import pytest
import yaml

from qr import rollout
from qr.sim.synth import SynthConfig, simulate_truth

from conftest import VEHICLES, run_cli

DRAG_FLAP = [{"name": "linear_drag", "parameters": {"kx": 0.3, "ky": 0.3, "kz": 0.15}},
             {"name": "blade_flapping", "parameters": {"k": 0.03}}]


@pytest.fixture(scope="module")
def truth():
    from qr.vehicle import load_vehicle

    v = load_vehicle(VEHICLES / "asctec_hummingbird.yaml")
    return v, simulate_truth(v, DRAG_FLAP, SynthConfig(duration=20, rate=100, seed=3))


def _models(v):
    return {"hold": "hold", "rate_frozen": ("rate_frozen", v), "nominal": (v, []), "true": (v, DRAG_FLAP)}


def test_the_true_model_reproduces_a_noise_free_flight_and_the_nominal_does_not(truth):
    v, tr = truth
    res = {k: rollout.summary(*s) for k, s in rollout.score(tr, tr, 50, 2, _models(v)).items()}
    true, nom = res["true"], res["nominal"]
    # the true plant started from the true state: only the hold of the rotor speeds over a step differs
    assert rollout.at(true, 50, "p") < 0.01 and rollout.at(true, 50, "R") < 0.02
    assert rollout.at(nom, 50, "p") > 10 * rollout.at(true, 50, "p")
    assert rollout.at(nom, 50, "R") > 10 * rollout.at(true, 50, "R")
    assert nom["w"]["simerr"] > 10 * true["w"]["simerr"]
    # errors grow with the horizon
    assert rollout.at(nom, 1, "p") < rollout.at(nom, 10, "p") < rollout.at(nom, 50, "p")


def test_hold_is_the_motion_itself_and_rate_frozen_holds_the_rate(truth):
    v, tr = truth
    res = {k: rollout.summary(*s) for k, s in rollout.score(tr, tr, 20, 2, _models(v)).items()}
    p = tr[["px", "py", "pz"]].to_numpy()
    for h in (1, 7, 20):
        direct = np.linalg.norm(p[h:] - p[:-h], axis=1).mean()
        assert rollout.at(res["hold"], h, "p") == pytest.approx(direct, rel=1e-9)
    assert res["rate_frozen"]["w"]["mae"] == pytest.approx(res["hold"]["w"]["mae"], rel=1e-9)
    assert res["hold"]["p"]["simerr"] == pytest.approx(sum(res["hold"]["p"]["mae"]))


def test_missing_truth_and_input_gaps_remove_exactly_the_windows_the_spec_says(truth):
    v, tr = truth
    n, H = len(tr), 10
    base = rollout.score(tr, tr, H, 2, {"hold": "hold"})["hold"][1]
    assert list(base[:, 0]) == [n - h for h in range(1, H + 1)]  # every start, every h inside the flight
    meas = tr.copy()
    meas.loc[500, ["px", "py", "pz"]] = np.nan  # one missing mocap position
    c = rollout.score(tr, meas, H, 2, {"hold": "hold"})["hold"][1]
    assert np.all(base[:, 0] - c[:, 0] == 1)  # each h loses the one window whose i + h is sample 500
    assert np.array_equal(base[:, 2], c[:, 2])  # the attitude is still there
    meas = tr.copy()
    meas.loc[300:304, ["u1", "u2", "u3", "u4"]] = np.nan  # a 5-sample rotor-speed gap; max_input_gap 2
    c = rollout.score(tr, meas, H, 2, {"hold": "hold"})["hold"][1]
    # rows 302-304 sit deeper than 2 samples in the gap: starts 302 - H + 1 ... 304 are skipped
    assert base[0, 0] - c[0, 0] == H + 2


def _synth(tmp_path):
    from qr.sim.synth import write_synth
    from qr.vehicle import load_vehicle

    v = load_vehicle(VEHICLES / "asctec_hummingbird.yaml")
    write_synth(tmp_path / "s", v, DRAG_FLAP, SynthConfig(duration=20, rate=100, seed=4))
    nominal = yaml.safe_load((tmp_path / "s" / "vehicle.yaml").read_text())
    (tmp_path / "true.yaml").write_text(yaml.safe_dump({**nominal, "effects": DRAG_FLAP}))
    return tmp_path / "s" / "flight.csv", tmp_path / "s" / "vehicle.yaml", tmp_path / "true.yaml"


def test_the_spec_command_line_literally(tmp_path):
    """``qr evaluate FLIGHT.csv --vehicle V.yaml --vehicle W.yaml --out OUTDIR [HYDRA_OVERRIDES...]``."""
    flight, nominal, true = _synth(tmp_path)
    out = tmp_path / "ev"
    r = subprocess.run([sys.executable, "-m", "qr.cli", "evaluate", str(flight), "--vehicle", str(nominal),
                        "--vehicle", str(true), "--out", str(out), "evaluate.horizon=30"],
                       capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    doc = json.loads((out / "evaluation.json").read_text())
    assert doc["schema"] == "qr.evaluation/1" and doc["flights"] == [str(flight)]
    assert doc["horizon"] == 30 and doc["dt"] == pytest.approx(0.01)
    assert set(doc["models"]) == {"hold", "rate_frozen", "vehicle.yaml", "true.yaml"}
    for block in doc["models"].values():
        assert set(block) == {"p", "v", "R", "w"} and len(block["p"]["mae"]) == 30
    assert set(doc["per_flight"]) == {str(flight)}
    # noisy measurements and a filtered start: the true model is still far better than the nominal one
    m = doc["models"]
    assert m["true.yaml"]["R"]["mae"][-1] < 0.25 * m["vehicle.yaml"]["R"]["mae"][-1]
    assert m["true.yaml"]["p"]["mae"][-1] < 0.5 * m["vehicle.yaml"]["p"]["mae"][-1]
    report = (out / "report.md").read_text()
    assert "| true.yaml |" in report and (out / "figures" / "rollout_mae.png").stat().st_size > 0


@pytest.mark.parametrize("extra, needle", [
    (["evaluate.horizon=0"], "evaluate.horizon"),
    (["evaluate.max_input_gap=-1"], "evaluate.max_input_gap"),
    (["evaluate.bogus=1"], "evaluate.bogus"),
])
def test_bad_settings_are_one_line_and_nothing_is_written(tmp_path, capsys, extra, needle):

    flight, nominal, _ = _synth(tmp_path)
    status, _, err = run_cli(["evaluate", flight, "--vehicle", nominal, "--out", tmp_path / "ev", *extra], capsys)
    assert status == 2 and needle in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "ev").exists()


def test_the_same_vehicle_twice_is_refused(tmp_path, capsys):

    flight, nominal, _ = _synth(tmp_path)
    status, _, err = run_cli(["evaluate", flight, "--vehicle", nominal, "--vehicle", nominal,
                              "--out", tmp_path / "ev"], capsys)
    assert status == 2 and "twice" in err and not (tmp_path / "ev").exists()


def test_flights_held_out_by_flight():
    from qr.holdout import held_out_by_flight

    fl = [f"f{i}" for i in range(7)]
    train, test = held_out_by_flight(fl)
    assert test == ["f2", "f5"] and train == ["f0", "f1", "f3", "f4", "f6"]
    assert held_out_by_flight(["a", "b"]) == (["a"], ["b"])


def test_a_tracked_diagnosis_logs_the_rollout_at_the_horizon(tmp_path, monkeypatch):
    """The diagnosis's MLflow run carries each model's MAE at h = H (the rollout block of diagnosis.json)."""
    monkeypatch.setenv("QR_TRACKING", "on")
    from qr import tracking
    from qr.stages.diagnose import run_diagnosis

    flight, nominal, _ = _synth(tmp_path)
    doc = run_diagnosis([flight], nominal, tmp_path / "d", ["evaluate.horizon=20"], track=True, figures=False,
                        log=lambda m: None)
    ro = doc["rollout"]
    assert ro["horizon"] == 20 and set(ro["models"]) == {"hold", "rate_frozen", "nominal", "extended"}
    assert ro["dt"] == pytest.approx(0.01, rel=1e-9)  # the 100 Hz log's step: h = 20 is 0.2 s (evaluation.json's "dt")
    # the named drag and flapping make the extended model's attitude rollout better than the nominal one's
    assert ro["models"]["extended"]["R"]["mae"][-1] < 0.5 * ro["models"]["nominal"]["R"]["mae"][-1]
    run = tracking._client().search_runs([tracking.experiment_id("diagnose")])[0]
    assert run.data.metrics["rollout.extended.R_at_20"] == pytest.approx(ro["models"]["extended"]["R"]["mae"][-1])
    assert "rollout.rate_frozen.w_at_20" in run.data.metrics


def test_a_tracked_evaluation_logs_each_model_at_the_horizon_and_its_ratio(tmp_path, monkeypatch):
    monkeypatch.setenv("QR_TRACKING", "on")
    from qr import tracking
    from qr.stages.evaluate import run_evaluation

    flight, nominal, true = _synth(tmp_path)
    doc = run_evaluation([flight], [nominal, true], tmp_path / "e", ["evaluate.horizon=20"], figures=False,
                         log=lambda m: None, track="unit")
    (run,) = tracking._client().search_runs([tracking.experiment_id("evaluate")])
    m, models = run.data.metrics, doc["models"]
    assert run.info.run_name == "unit" and run.info.status == "FINISHED"
    for name in models:
        assert m[f"{name}.p_at_20"] == pytest.approx(models[name]["p"]["mae"][-1])
        assert m[f"{name}.w_ratio"] == pytest.approx(models[name]["w"]["mae"][-1] / models["rate_frozen"]["w"]["mae"][-1])
    assert m["rate_frozen.R_ratio"] == 1.0


def test_the_summed_share_sees_the_slow_error_a_rollout_integrates():
    """Residual of a constant label 1 left as a fast ±1 alternation: nothing explained sample by sample
    (R² = 1 − n/n = 0), everything summed over 2 samples (each pair sums to 0); a slow error (a
    constant 0.5 left) is a quarter of the variance either way.  Windows never cross a segment edge:
    two 5-sample segments give 4 + 4 windows, not 9 (with 9, the pair across the edge, +1 and +1,
    would show)."""
    from types import SimpleNamespace

    from qr.diagnose.held_out import summed_r2

    n = 10
    prep = SimpleNamespace(test=np.ones(n, bool), flight=np.repeat([0, 1], 5))
    y = np.ones((n, 2))
    fast = np.tile([1.0, -1.0, 1.0, -1.0, 1.0], 2)  # each segment: + - + - + (the edge: + then +)
    resid = np.column_stack([fast, np.full(n, 0.5)])
    r = summed_r2(prep, y, resid, 2)
    assert r.one_step == pytest.approx([0.0, 0.75])
    assert r.summed == pytest.approx([1.0, 0.75])


def test_the_rollout_sums_are_the_same_digits_on_one_thread_or_two(tmp_path):
    """The starts run in fixed interleaved chunks, so the sums do not depend on how many threads numba
    has (the test suite's workers run on one thread each: this runs in a process that has two)."""
    import os

    code = """
import numpy as np, numba
from qr import rollout
from qr.sim.synth import SynthConfig, simulate_truth
from qr.vehicle import load_vehicle
v = load_vehicle(%r)
tr = simulate_truth(v, %r, SynthConfig(duration=8, rate=100, seed=3))
models = {"rate_frozen": ("rate_frozen", v), "true": (v, %r)}
out = []
for n in (1, 2):
    numba.set_num_threads(n)
    out.append({k: s[0] for k, s in rollout.score(tr, tr, 30, 2, models).items()})
assert numba.get_num_threads() == 2
assert all(np.array_equal(out[0][k], out[1][k]) for k in models), "thread count changed the sums"
print("same")
""" % (str(VEHICLES / "asctec_hummingbird.yaml"), DRAG_FLAP, DRAG_FLAP)
    env = {**os.environ, "NUMBA_NUM_THREADS": "2"}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert r.returncode == 0 and r.stdout.strip() == "same", r.stderr[-2000:]


def test_the_held_out_models_are_the_diagnosis_in_memory_at_full_precision(tmp_path):
    """``Diagnosis.models()``: the extended (one-step) model carries the named effects' parameters at full
    precision (diagnosis.json states 6 digits) on the nominal vehicle's own rotor properties; the refined model
    is the written one without its torque remainder; the hybrid is the extended one plus that remainder.  The
    held-out protocol writes exactly these vehicles (read back equal) and labels them; on a flight the model
    does not describe (nothing written) the extended model is still the nominal one plus what was identified."""
    from types import SimpleNamespace

    from qr.diagnose.diagnosis import Diagnosis
    from qr.diagnose.fit import NamedEffect
    from qr.stages.evaluate_sets import held_out_models
    from qr.torque_remainder import N_FEATURES, block
    from qr.vehicle import load_vehicle

    nominal = load_vehicle(VEHICLES / "asctec_hummingbird.yaml")
    kx = 0.123456789123  # 0.123457 in diagnosis.json
    drag = NamedEffect("linear_drag", {"kx": kx, "ky": 0.2, "kz": 0.05}, {"kx": 0.01, "ky": 0.01, "kz": 0.01}, 0.5, [])
    remainder = block(np.full((3, N_FEATURES), 1e-4), "a test remainder")
    written = nominal.with_changes(effects=nominal.effects + [{"name": "linear_drag",
                                                               "parameters": {"kx": 0.13, "ky": 0.2, "kz": 0.05}}],
                                   rotor_inertia=2e-5, torque_remainder=remainder)
    m = Diagnosis.models(SimpleNamespace(vehicle=nominal, extended_vehicle=written, effects=[drag], refinement=object()))
    assert m.nominal is nominal
    assert m.extended.effects == nominal.effects + [{"name": "linear_drag",
                                                     "parameters": {"kx": kx, "ky": 0.2, "kz": 0.05}}]
    assert m.extended.rotor_inertia == nominal.rotor_inertia != 2e-5 and "torque_remainder" not in m.extended.raw
    assert m.refined.effects[-1]["parameters"]["kx"] == 0.13 and m.refined.rotor_inertia == 2e-5
    assert "torque_remainder" not in m.refined.raw
    assert m.hybrid.raw["torque_remainder"] == remainder and m.hybrid.effects == m.extended.effects
    assert m.hybrid.rotor_inertia == nominal.rotor_inertia

    files, vehicles, labels = held_out_models(VEHICLES / "asctec_hummingbird.yaml", SimpleNamespace(models=lambda: m),
                                              {"refine": {}}, tmp_path / "models")
    assert labels == ["nominal", "extended", "physical (refined)", "hybrid"]
    assert vehicles == [m.nominal, m.extended, m.refined, m.hybrid]
    assert [p.rsplit("/", 1)[-1] for p in files[1:]] == ["extended_physical.yaml", "refined_physical.yaml",
                                                         "extended_vehicle.yaml"]
    for f, v in zip(files[1:], vehicles[1:]):
        assert load_vehicle(f).to_dict() == v.to_dict()

    misfit = Diagnosis.models(SimpleNamespace(vehicle=nominal, extended_vehicle=nominal, effects=[drag], refinement=None))
    assert misfit.refined is None and misfit.hybrid is None and misfit.extended.effects[-1]["parameters"]["kx"] == kx
