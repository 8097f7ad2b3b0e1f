"""Residual models: a linear ANN is ridge, seeded fits repeat, saved models reload, the GP is scikit-learn's."""

import numpy as np
import pytest

from qr import models
from qr.errors import QrInputError


def _linear_data(n=600, d=5, k=3, seed=0, noise=0.05):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, d)) * np.array([1.0, 3.0, 0.2, 10.0, 1.0])[:d] + np.array([0, 5, 0, 100, -2])[:d]
    W = rng.normal(size=(k, d))
    y = X @ W.T + np.array([0.5, -1.0, 2.0])[:k] + noise * rng.normal(size=(n, k))
    return X, y


def _smooth_data(n, seed=0, noise=0.1):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-2, 2, size=(n, 2))
    y = np.sin(2 * X[:, :1]) + 0.5 * X[:, 1:] ** 2 + noise * rng.normal(size=(n, 1))
    return X, y


def test_linear_ann_collapses_to_ridge():
    """A network with linear activations is the affine map W x + b (thesis eq. 4.36) that least squares finds."""
    X, y = _linear_data()
    ann = models.fit("ann", X, y, {"layers": 2, "neurons": 5, "activation": "linear", "weight_decay": 0.0,
                                   "max_iter": 3000})
    ridge = models.fit("linear", X, y, {"alpha": 0.0})
    W, b = ann.collapse()
    Wr, br = ridge.collapse()
    ref = np.linalg.lstsq(np.hstack([X, np.ones((len(X), 1))]), y, rcond=None)[0]  # independent: OLS
    np.testing.assert_allclose(Wr, ref[:-1].T, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(br, ref[-1], rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(W, Wr, rtol=1e-3, atol=1e-4)
    np.testing.assert_allclose(b, br, rtol=1e-3, atol=1e-3)
    np.testing.assert_allclose(X @ W.T + b, ann.predict(X), atol=1e-9)  # the collapse is the network


def test_ridge_penalty_shrinks_towards_zero():
    X, y = _linear_data()
    W0, _ = models.fit("linear", X, y, {"alpha": 0.0}).collapse()
    W1, _ = models.fit("linear", X, y, {"alpha": 10.0}).collapse()
    assert np.linalg.norm(W1 * X.std(axis=0)) < 0.5 * np.linalg.norm(W0 * X.std(axis=0))


def test_collapse_refuses_a_nonlinear_network():
    X, y = _linear_data(n=50)
    relu = models.fit("ann", X, y, {"layers": 1, "neurons": 3, "activation": "relu", "max_iter": 20})
    with pytest.raises(QrInputError, match="not an affine map"):
        relu.collapse()


@pytest.mark.parametrize("optimizer", ["lbfgs", "adam"])
def test_ann_is_seeded_and_deterministic(optimizer):
    X, y = _smooth_data(300)
    cfg = {"layers": 2, "neurons": 8, "activation": "tanh", "optimizer": optimizer, "max_iter": 200}
    val = (X[:60], y[:60])
    a = models.fit("ann", X[60:], y[60:], {**cfg, "seed": 3}, val=val).predict(X)
    b = models.fit("ann", X[60:], y[60:], {**cfg, "seed": 3}, val=val).predict(X)
    c = models.fit("ann", X[60:], y[60:], {**cfg, "seed": 4}, val=val).predict(X)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_early_stopping_keeps_the_best_validation_weights():
    X, y = _smooth_data(200, noise=0.5)
    m = models.fit("ann", X[:100], y[:100], {"layers": 2, "neurons": 30, "activation": "tanh", "weight_decay": 0.0,
                                             "patience": 10}, val=(X[100:], y[100:]))
    assert m.info["stopped"] == "early_stopping"
    assert m.info["best_iteration"] == m.info["iterations"] - 10
    val_mse = np.mean(((m.predict(X[100:]) - y[100:]) / y[:100].std(axis=0)) ** 2)
    assert val_mse == pytest.approx(m.info["val_mse_standardised"], rel=1e-9)


@pytest.mark.parametrize("kind,cfg", [("ann", {"layers": 1, "neurons": 4, "activation": "relu", "max_iter": 50}),
                                      ("linear", {}), ("gpr", {"kernel": "matern52_ard", "max_exact": 100,
                                                               "inducing": 40})])
def test_saved_model_reloads_with_its_metadata(tmp_path, kind, cfg):
    import torch

    X, y = _smooth_data(150)
    meta = {"inputs": ["v_b"], "target": "f_a", "feature_names": ["a", "b"], "leaks_target": False}
    m = models.fit(kind, X, y, cfg, meta=meta)
    m.save(tmp_path / "m")
    back = models.load(tmp_path / "m")
    assert (back.kind, back.inputs, back.target, back.leaks_target) == (kind, ["v_b"], "f_a", False)
    np.testing.assert_array_equal(back.predict(X), m.predict(X))
    if kind == "ann":
        state = torch.load(tmp_path / "m" / "weights.pt", weights_only=True)
        assert set(state) == {"state_dict", "x_mean", "x_std", "y_mean", "y_std"}


def test_load_rejects_a_non_model(tmp_path):
    with pytest.raises(QrInputError, match="not a saved qr model"):
        models.load(tmp_path)


def test_bad_model_options_are_one_clear_error():
    X, y = _linear_data(n=20)
    with pytest.raises(QrInputError, match="unknown model kind 'svm'"):
        models.fit("svm", X, y)
    with pytest.raises(QrInputError, match="unknown activation 'sigmoid'"):
        models.fit("ann", X, y, {"activation": "sigmoid"})
    with pytest.raises(QrInputError, match="unknown GPR kernel 'rbf'"):
        models.fit("gpr", X, y, {"kernel": "rbf"})
    with pytest.raises(QrInputError, match="has no option"):
        models.fit("linear", X, y, {"lambda": 1.0})


@pytest.mark.parametrize("kernel", ["se_ard", "matern32_ard", "matern52_ard", "rq"])
def test_fast_marginal_likelihood_is_scikit_learns(kernel):
    from sklearn.gaussian_process import GaussianProcessRegressor

    from qr.models.gpr import _fast_gpr_class, make_kernel

    X, y = _smooth_data(120)
    for mean in ("ridge", "dot"):
        k = make_kernel(kernel, 2, mean)
        ref = GaussianProcessRegressor(k, optimizer=None).fit(X, y[:, 0])
        fast = _fast_gpr_class()(k, optimizer=None).fit(X, y[:, 0])
        theta = k.theta + 0.2
        (a, ga), (b, gb) = ref.log_marginal_likelihood(theta, True), fast.log_marginal_likelihood(theta, True)
        assert b == pytest.approx(a, rel=1e-10)
        np.testing.assert_allclose(gb, ga, rtol=1e-8, atol=1e-10)


def test_gpr_posterior_is_scikit_learns_and_starts_from_the_data_std():
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import WhiteKernel

    X, y = _smooth_data(200)
    m = models.fit("gpr", X, y, {"kernel": "se_ard", "mean": "zero", "hyper_subset": 200},
                   meta={"feature_names": ["x1", "x2"]})
    assert not m.info["sparse"]
    kernel = m.post[0].signal + WhiteKernel(m.post[0].noise, "fixed")
    ref = GaussianProcessRegressor(kernel, optimizer=None, alpha=0.0).fit(m.xs(X), m.rs[:, 0])
    Xq = np.random.default_rng(1).uniform(-2, 2, size=(50, 2))
    mean, std = m.predict(Xq, return_std=True)
    rm, rs = ref.predict(m.xs(Xq), return_std=True)
    np.testing.assert_allclose(mean[:, 0], m.b[0] + m.r_scale[0] * rm, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(std[:, 0], m.r_scale[0] * rs, rtol=1e-6, atol=1e-8)
    hp = m.info["hyperparameters"][0]
    assert hp[1]["name"] == "length scale (x1)" and hp[1]["initial"] == pytest.approx(X[:, 0].std())
    assert hp[0]["initial"] == pytest.approx(y[:, 0].var())


def test_gpr_band_covers_95_percent_and_the_sparse_posterior_matches_the_exact_one():
    X, y = _smooth_data(2400, seed=2, noise=0.2)
    Xt, yt = _smooth_data(2000, seed=3, noise=0.2)
    exact = models.fit("gpr", X, y, {"max_exact": 3000})
    sparse = models.fit("gpr", X, y, {"max_exact": 1000, "inducing": 300})
    assert sparse.info["sparse"] and not exact.info["sparse"]
    me, se = exact.predict(Xt, return_std=True)
    ms, ss = sparse.predict(Xt, return_std=True)
    assert np.sqrt(np.mean((ms - me) ** 2)) < 0.02  # next to the noise std 0.2
    for mean, std in ((me, se), (ms, ss)):
        assert np.sqrt(np.mean((yt - mean) ** 2)) < 0.22
        assert 0.93 < np.mean(np.abs(yt - mean) <= 1.96 * std) < 0.97


def test_gpr_basis_is_the_linear_mean():
    X, y = _linear_data(n=300, d=2, k=1, noise=0.01)
    m = models.fit("gpr", X, y, {"mean": "ridge"}, meta={"feature_names": ["v_b.x", "v_b.y"]})
    W, b = models.fit("linear", X, y).collapse()
    basis = m.info["basis"][0]
    assert basis["beta_0 (intercept)"] == pytest.approx(b[0])
    assert [basis["beta (v_b.x)"], basis["beta (v_b.y)"]] == pytest.approx(list(W[0]))
