"""Force-model adapters of the study: explicit W, b; catalog; extended vehicle; learned model; fits."""

import sys
import types

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from conftest import VEHICLES
from qr.effects import Signals, parse_effect_spec
from qr.errors import QrInputError
from qr.frames import rot_to_quat
from qr.sim.disturbance import (CatalogForce, LearnedForce, LinearForce, extended_vehicle, features, fit_linear,
                                quaternions)


def _signals(n=200, seed=0):
    rng = np.random.default_rng(seed)
    R = Rotation.random(n, random_state=seed).as_matrix()
    return Signals(R, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=(n, 3)),
                   rng.normal(size=(n, 3)), rng.uniform(4000, 8000, (n, 4)), rng.normal(size=(n, 4)),
                   rng.normal(size=(n, 3)))


def test_features_concatenate_groups_in_order_and_quaternions_match_frames():
    s = _signals()
    X = features(s, ["u", "v_b", "q"], u_scale=1e3)
    np.testing.assert_allclose(X[:, :4], s.u / 1e3)
    np.testing.assert_allclose(X[:, 4:7], s.v_b)
    np.testing.assert_allclose(X[:, 7:], rot_to_quat(s.R), atol=1e-12)
    np.testing.assert_allclose(quaternions(s.R), rot_to_quat(s.R), atol=1e-12)


def test_linear_force_blocks_are_in_input_units():
    W = np.arange(21.0).reshape(3, 7)
    m = LinearForce(W, [1, 2, 3], ("v_b", "u"), u_scale=1e4)
    np.testing.assert_array_equal(m.block("v_b"), W[:, :3])
    np.testing.assert_allclose(m.block("u"), W[:, 3:] / 1e4)
    np.testing.assert_array_equal(m.block("a_b"), np.zeros((3, 3)))
    with pytest.raises(QrInputError, match="need"):
        LinearForce(np.zeros((3, 5)), [0, 0, 0], ("v_b", "u"))
    with pytest.raises(QrInputError, match="unknown input group"):
        LinearForce(np.zeros((3, 3)), [0, 0, 0], ("speed",))


def test_fit_linear_recovers_a_linear_force():
    s = _signals(500)
    W = np.array([[-0.3, 0, 0, 1e-4, 0, 0, 0], [0, -0.2, 0, 0, 2e-4, 0, 0], [0, 0, -0.1, 0, 0, 0, -1e-4]])
    f = features(s, ["v_b", "u"]) @ W.T + [0.1, -0.2, 0.3]
    m = fit_linear(s, f, ["v_b", "u"])
    np.testing.assert_allclose(m.W, W, atol=1e-9)
    np.testing.assert_allclose(m.b, [0.1, -0.2, 0.3], atol=1e-6)


def test_catalog_force_is_the_effect_terms(hummingbird):
    s = _signals()
    cf = CatalogForce([parse_effect_spec("linear_drag:kx=0.3,ky=0,kz=0"),
                       parse_effect_spec("wind_force:fx=0,fy=0,fz=-0.5")], hummingbird)
    expected = -0.3 * s.v_b * [1, 0, 0] + np.einsum("nji,j->ni", s.R, [0, 0, -0.5])
    np.testing.assert_allclose(cf.predict(s), expected, atol=1e-12)


def test_extended_vehicle_file_gives_nominal_plus_effects(tmp_path):
    raw = yaml.safe_load((VEHICLES / "asctec_hummingbird.yaml").read_text())
    raw["effects"] = [{"name": "linear_drag", "parameters": {"kx": 0.2, "ky": 0.2, "kz": 0.05}}]
    p = tmp_path / "extended_vehicle.yaml"
    p.write_text(yaml.safe_dump(raw))
    nominal, effects = extended_vehicle(p)
    assert not nominal.effects and nominal.mass == raw["mass"]
    assert effects[0]["parameters"] == {"kx": 0.2, "ky": 0.2, "kz": 0.05}
    del raw["effects"]
    p.write_text(yaml.safe_dump(raw))
    with pytest.raises(QrInputError, match="not an extended vehicle"):
        extended_vehicle(p)


@pytest.fixture
def fake_learning_stage(monkeypatch):
    """Stand-ins for qr.models / qr.datasets with the learning stage's announced interface."""
    W = np.array([[-0.25, 0, 0, 0, 0, 0], [0, -0.25, 0, 0, 0, 0], [0, 0, -0.1, 0, 0, 0.0]])
    b = np.array([0.01, 0.02, -0.03])

    class Model:
        inputs = ["v_b", "a_b"]
        target = "f_a"

        def predict(self, X):
            return X @ W.T + b

        def collapse(self):
            return W, b

    models = types.ModuleType("qr.models")
    models.load = lambda path: Model()
    datasets = types.ModuleType("qr.datasets")
    datasets.features = lambda s, inputs: features(s, inputs)
    monkeypatch.setitem(sys.modules, "qr.models", models)
    monkeypatch.setitem(sys.modules, "qr.datasets", datasets)
    import qr

    monkeypatch.setattr(qr, "models", models, raising=False)
    monkeypatch.setattr(qr, "datasets", datasets, raising=False)
    return W, b


def test_learned_model_adapter(fake_learning_stage, tmp_path):
    W, b = fake_learning_stage
    s = _signals()
    m = LearnedForce(tmp_path, "ann")
    np.testing.assert_allclose(m.predict(s), np.hstack([s.v_b, s.a_b]) @ W.T + b)
    lin = m.as_linear()
    np.testing.assert_array_equal(lin.block("a_b"), W[:, 3:])
    with pytest.raises(QrInputError, match="not found"):
        LearnedForce(tmp_path / "missing")


def test_learned_model_in_the_study(fake_learning_stage, tmp_path):
    """Wired like the workflow will: a leaking learned model is refused for tracking, analysed for stability."""
    from qr.sim.simulation import stability_study, tracking_study

    spec = {"model": "learned", "path": str(tmp_path)}
    with pytest.raises(QrInputError, match="leaks the target"):
        tracking_study({"vehicle": "asctec_hummingbird", "duration": 1.0,
                        "sources": {"l": {"plant": {"force": spec}}}}, progress=False)
    table = stability_study({"vehicle": "asctec_hummingbird", "stability": {
        "duration_s": 1.0, "models": {"learned": spec}}}, progress=False).table
    assert table.loc[0, "model"] == "learned" and table.loc[0, "lagged_status"] == "ok"
    assert table.loc[0, "n_above_one"] == 0


def test_input_groups_agree_with_the_learning_stage():
    datasets = pytest.importorskip("qr.datasets")
    from qr.sim.disturbance import GROUP_SIZES

    assert GROUP_SIZES == {g: len(c) for g, c in datasets.GROUPS.items()}
    s = _signals()
    groups = list(GROUP_SIZES)
    np.testing.assert_allclose(features(s, groups), datasets.features(s, groups), atol=1e-12)


def test_learned_adapter_with_a_saved_model_of_the_learning_stage(tmp_path):
    models = pytest.importorskip("qr.models")
    s = _signals(300)
    W = np.array([[-0.3, 0, 0, 1e-5, 0, 0, 0], [0, -0.3, 0, 0, 0, 1e-5, 0], [0, 0, -0.1, 0, 0, 0, 0]])
    y = features(s, ["v_b", "u"]) @ W.T + [0.0, 0.1, -0.2]
    meta = {"inputs": ["v_b", "u"], "target": "f_a", "leaks_target": False}
    models.fit("linear", features(s, ["v_b", "u"]), y, {"alpha": 0.0}, meta=meta).save(tmp_path / "m")
    m = LearnedForce(tmp_path / "m")
    np.testing.assert_allclose(m.predict(s), y, atol=1e-8)
    np.testing.assert_allclose(m.as_linear().block("v_b"), W[:, :3], atol=1e-8)
