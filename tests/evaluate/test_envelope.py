"""The training envelope (qr.envelope) and its block in ``qr evaluate``'s output.

Independent expectations: windows built by hand, where the samples beyond the training extremes are
placed, so the windows that reach them are known by counting (a state at sample j is in the windows
starting at j − H … j; an input at j in those starting at j − H + 1 … j); a flight is inside its own
envelope (every window covers only samples that built it).
"""

import json

import numpy as np
import pytest

from qr.envelope import Envelope, check, covered, spans
from qr.rollout import Windows


def _windows(n=120, v=1.0, u=100.0):
    t = np.arange(n) * 0.01
    X0 = np.zeros((n, 13))
    X0[:, 3] = v  # 1 m/s along x
    X0[:, 6] = 1.0  # level
    U = np.full((n, 4), u)
    nan = np.full((n, 3), np.nan)
    return Windows(t, X0, U, np.ones(n, bool), nan, np.full((n, 4), np.nan), X0[:, 3:6].copy(), X0[:, 10:13].copy())


def _tilted(angle):
    return [np.cos(angle / 2), np.sin(angle / 2), 0.0, 0.0]  # about body x


def test_the_windows_that_reach_a_sample_beyond_the_envelope_are_flagged_exactly():
    H = 10
    train = _windows()
    train.X0[5, 6:10] = _tilted(0.2)  # tilt up to 0.2 rad
    train.X0[7, 10] = -0.5  # roll rate -0.5 ... 0
    env = Envelope.of([train], H)
    assert env.speed_max == 1.0 and env.tilt_max == pytest.approx(0.2) and env.rate_min[0] == -0.5
    test = _windows()
    test.X0[40:45, 3] = 2.0  # faster than any training sample, samples 40-44
    test.U[60, 2] = 101.0  # rotor 3 above its training maximum at sample 60
    test.X0[80, 6:10] = _tilted(0.3)  # more tilt at 80
    test.X0[95, 10] = -0.4  # a roll rate inside the range: not outside
    o = env.outside(test, H)
    starts = np.arange(len(test.t))
    assert np.array_equal(np.flatnonzero(o["speed"]), starts[30:45])  # 40 - H ... 44
    assert np.array_equal(np.flatnonzero(o["rotor"]), starts[51:61])  # an input: 60 - H + 1 ... 60
    assert np.array_equal(np.flatnonzero(o["tilt"]), starts[70:81])
    assert not o["rate"].any()
    assert o["any"].sum() == 15 + 10 + 11  # the three runs do not overlap
    doc = check(env, [test], H)
    assert doc.windows == 120 and doc.outside == 36 and doc.share_outside == pytest.approx(36 / 120)
    assert doc.share_outside_by["speed"] == pytest.approx(15 / 120)
    np.testing.assert_allclose(doc.outside_spans_s, [[0.30, 0.44], [0.51, 0.60], [0.70, 0.80]])


def test_a_flight_is_inside_its_own_envelope_and_only_the_covered_samples_build_it():
    H = 10
    w = _windows()
    w.X0[:, 3] = np.linspace(0, 3, len(w.t))
    ok = np.zeros(len(w.t), bool)
    ok[20:50] = True  # scored starts 20-49: they reach samples 20-59
    w = Windows(w.t, w.X0, w.U, ok, w.tp, w.tq, w.tv, w.tw)
    assert np.array_equal(np.flatnonzero(covered(ok, H)), np.arange(20, 60))
    env = Envelope.of([w], H)
    assert env.speed_max == pytest.approx(w.X0[59, 3])  # not the faster samples no window reaches
    assert not env.outside(w, H)["any"].any()
    assert spans(np.arange(5.0), np.array([True, True, False, True, True])) == [[0.0, 1.0], [3.0, 4.0]]


def test_qr_evaluate_flags_a_faster_flight_and_not_the_training_one(tmp_path):
    """``evaluate.trained_on``: a flight flown faster than the training flight leaves its envelope; the
    training flight itself does not (evaluation.json's block ``envelope``, the report's section)."""
    from qr.sim.synth import SynthConfig, write_synth
    from qr.sim.trajectory import TrajectoryConfig
    from qr.stages.evaluate import run_evaluation
    from qr.vehicle import load_vehicle

    from conftest import VEHICLES

    v = load_vehicle(VEHICLES / "asctec_hummingbird.yaml")
    write_synth(tmp_path / "slow", v, [], SynthConfig(duration=8, rate=100, seed=1,
                                                      trajectory=TrajectoryConfig(v_max=0.8, tilt_max_deg=8)))
    write_synth(tmp_path / "fast", v, [], SynthConfig(duration=8, rate=100, seed=2,
                                                      trajectory=TrajectoryConfig(v_max=2.5, tilt_max_deg=25)))
    slow, fast, veh = tmp_path / "slow" / "flight.csv", tmp_path / "fast" / "flight.csv", tmp_path / "slow" / "vehicle.yaml"
    doc = run_evaluation([fast, slow], [veh], tmp_path / "ev", [f"evaluate.trained_on=[{slow}]", "evaluate.horizon=20"],
                         figures=False, log=lambda m: None)
    env = doc["envelope"]
    assert env["trained_on"] == [str(slow)]
    assert env["per_flight"][str(slow)]["outside"] == 0
    assert env["per_flight"][str(fast)]["share_outside"] > 0.5
    assert env["per_flight"][str(fast)]["share_outside_by"]["speed"] > 0.5
    assert env["limits"]["speed_max"] < 1.2  # the slow flight's (its reference peaks at 0.8 m/s)
    n = env["per_flight"][str(fast)]["windows"] + env["per_flight"][str(slow)]["windows"]
    assert env["windows"] == n and env["outside"] == env["per_flight"][str(fast)]["outside"]
    saved = json.loads((tmp_path / "ev" / "evaluation.json").read_text())
    assert saved["envelope"]["share_outside"] == pytest.approx(env["outside"] / n)
    report = (tmp_path / "ev" / "report.md").read_text()
    sentence = f"{env['outside']} of {n} windows"
    assert "## Outside the training envelope" in report and sentence in report


def test_the_held_out_mode_scores_what_the_split_holds_out_and_checks_it_against_the_rest(tmp_path):
    """``qr evaluate`` with a trajectory ``evaluate.split``: of the flights given, those of the held-out
    trajectory are scored, the others are the training side whose envelope the windows are checked against
    (the spec's command line, through a subprocess)."""
    import subprocess
    import sys

    import yaml

    from qr.sim.synth import SynthConfig, write_synth
    from qr.sim.trajectory import TrajectoryConfig
    from qr.vehicle import load_vehicle

    from conftest import VEHICLES

    v = load_vehicle(VEHICLES / "asctec_hummingbird.yaml")
    for name, vmax, seed in (("hover", 0.5, 1), ("dash", 2.5, 2)):
        write_synth(tmp_path / name, v, [], SynthConfig(duration=6, rate=100, seed=seed,
                                                        trajectory=TrajectoryConfig(v_max=vmax, tilt_max_deg=20)))
        (tmp_path / name / "flight.csv").rename(tmp_path / f"{name}.csv")
    data = tmp_path / "d.yaml"
    data.write_text(yaml.safe_dump({"root": ".", "sets": {"s": {"vehicle": "v", "flights": ["hover", "dash"], "flown": [
        {"flights": ["hover"], "trajectory": "hover"}, {"flights": ["dash"], "trajectory": "dash"}]}}}))
    r = subprocess.run([sys.executable, "-m", "qr.cli", "evaluate", "hover.csv", "dash.csv", "--vehicle",
                        str(tmp_path / "hover" / "vehicle.yaml"), "--out", "ev", "evaluate.horizon=20",
                        "evaluate.split.kind=trajectory", "evaluate.split.trajectories=[dash]",
                        f"evaluate.split.data={data}", "evaluate.split.set=s"],
                       capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "ev" / "evaluation.json").read_text())
    assert doc["flights"] == ["dash.csv"] and doc["split"]["test"] == ["dash.csv"]
    assert doc["split"]["held_out"] == "dash" and doc["envelope"]["trained_on"] == ["hover.csv"]
    assert doc["envelope"]["share_outside"] > 0.5
    assert "Held out (`evaluate.split.kind=trajectory`): dash" in (tmp_path / "ev" / "report.md").read_text()
