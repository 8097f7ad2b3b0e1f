"""The learned torque remainder (qr.torque_remainder): a hybrid, applied wherever the vehicle flies.

A synthetic flight hides aerodynamic rate damping (τ = −c ω, c = 0.01 N m s on roll and pitch; not a
catalog effect) through the vehicle file's own ``torque_remainder`` in the TRUE plant.  Diagnosed with
a remainder, the learned map recovers the damping (the ω weights within 25 % of −c), the hybrid's
held-out roll/pitch torque RMSE drops well below the physical model's, and its rollout holds the
attitude better.  A malformed remainder in a vehicle file is one line.
"""

import numpy as np
import pandas as pd
import pytest
import yaml

from conftest import VEHICLES, run_cli
from qr.stages.diagnose import run_diagnosis
from qr.sim.synth import SynthConfig, write_synth
from qr.vehicle import load_vehicle

C = 0.01


def _damping():
    W = np.zeros((3, 11))
    W[0, 3] = W[1, 4] = -C
    return {"weights": W.tolist()}


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("rem")
    raw = yaml.safe_load((VEHICLES / "asctec_hummingbird.yaml").read_text())
    raw.pop("extends", None)
    true = load_vehicle(VEHICLES / "asctec_hummingbird.yaml").with_changes(torque_remainder=_damping())
    write_synth(tmp / "s", true, [], SynthConfig(duration=40, rate=100, seed=2))
    nominal = tmp / "s" / "vehicle.yaml"
    # candidates without torque terms: a catalog effect (a negative flapping, v and ω correlate in these
    # trajectories) would otherwise take part of the damping, and the remainder only the rest
    doc = run_diagnosis([tmp / "s" / "flight.csv"], nominal, tmp / "d", ["diagnose.torque_remainder_ridge=0.001",
                        "evaluate.horizon=30", "diagnose.candidates=[linear_drag,wind_force]"], track=False,
                        figures=False, log=lambda m: None)
    doc["_dir"] = tmp
    return doc, load_vehicle(tmp / "d" / "extended_vehicle.yaml")


def test_the_remainder_recovers_a_damping_the_catalog_lacks(diagnosed):
    doc, ext = diagnosed
    W = np.asarray(ext.raw["torque_remainder"]["weights"])
    assert W[0, 3] == pytest.approx(-C, rel=0.25) and W[1, 4] == pytest.approx(-C, rel=0.25)
    # what the hybrid takes off the held-out torque variance is the damping's own variance, C² <ω²>
    # (the rest is the label's noise, which no model removes)
    rem = doc["torque_remainder"]
    truth = pd.read_parquet(doc["_dir"] / "s" / "truth.parquet")
    a, b = doc["split"]["test"]
    truth = truth[(truth["t"] >= a) & (truth["t"] <= b)]
    for k, w in ((0, "wx"), (1, "wy")):
        removed = rem["extended_torque_rmse"][k] ** 2 - rem["hybrid_torque_rmse"][k] ** 2
        assert removed == pytest.approx(C**2 * np.mean(truth[w].to_numpy() ** 2), rel=0.4)


def test_the_hybrid_rollout_holds_the_attitude_better(diagnosed):
    doc, _ = diagnosed
    m = doc["rollout"]["models"]
    assert m["hybrid"]["R"]["mae"][-1] < 0.7 * m["extended"]["R"]["mae"][-1]
    assert m["hybrid"]["w"]["mae"][-1] < 0.7 * m["extended"]["w"]["mae"][-1]


@pytest.mark.parametrize("bad", [{"weights": [[0.0] * 11] * 2}, {"weights": [[0.0] * 10] * 3}, [1, 2],
                                 {"weights": [[0.0] * 10 + ["x"]] * 3}])
def test_a_malformed_remainder_is_one_line(bad, tmp_path, capsys):
    raw = yaml.safe_load((VEHICLES / "asctec_hummingbird.yaml").read_text())
    raw["torque_remainder"] = bad
    path = tmp_path / "v.yaml"
    path.write_text(yaml.safe_dump(raw))
    status, _, err = run_cli(["synth", "--vehicle", path, "--duration", "2", "--out", tmp_path / "s"], capsys)
    assert status == 2 and "torque_remainder" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "s").exists()
