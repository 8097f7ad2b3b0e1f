"""The selection's decision rules, by hand: margins within numerical noise, effects the held-out part does
not support, and pairs that cancel where the flight spends its time."""

from __future__ import annotations

import numpy as np

from qr.diagnose.held_out import unsupported
from qr.identification.edge import EDGE, Margins, rank_key
from qr.identification.normal_equations import BlockStats, Columns
from qr.identification.selection import SelectionConfig, better, cancelling, choose_size


def test_a_margin_within_numerical_noise_is_decided_the_conservative_way():
    m = Margins()
    assert m.at_least(1.0 + 1e-3, 1.0) and not m.at_least(1.0 - 1e-3, 1.0)
    assert not m.at_least(1.0 + 0.1 * EDGE, 1.0, "a loss") and not m.at_least(1.0 - 0.1 * EDGE, 1.0, "a loss")
    assert m.at_most(1.0 + 0.1 * EDGE, 1.0, "a t", on_edge=True)  # the caller says which way is conservative
    assert m.on_edge == ["a loss", "a loss", "a t"] and abs(m.closest) <= EDGE


def test_losses_that_tie_to_numerical_noise_rank_the_same_everywhere():
    a, b = 1.2345678901234, 1.2345678901234 * (1 + 1e-14)
    assert rank_key(a) == rank_key(b)  # then simplicity and names order them
    assert rank_key(1.0) != rank_key(1.0 + 1e-6)


class FakeCV:
    """Cross-validation results set by hand: total loss per set, fold losses, paired t."""

    def __init__(self, loss, folds, t=5.0):
        self._loss, self._folds, self._t = loss, folds, t

    def loss(self, S):
        return self._loss[tuple(S)]

    def losses(self, S):
        return np.asarray(self._folds[tuple(S)], float)

    def paired_t(self, a, b, on=None):
        return self._t


def test_a_set_whose_gain_sits_on_min_gain_is_not_added_and_says_so():
    cfg = SelectionConfig()
    old, new = (), ("linear_drag",)
    L_old = 10.0
    L_new = (1 - cfg.min_gain) * L_old * (1 + 0.1 * EDGE)  # 1 % better to the last digits
    folds = {old: [2.0] * 5, new: [2.0 * (1 - cfg.min_gain)] * 5}
    cv = FakeCV({old: L_old, new: L_new}, folds)
    m = Margins()
    assert not better(cv, new, old, cfg, m) and m.on_edge
    cv = FakeCV({old: L_old, new: 0.9 * L_old}, {old: [2.0] * 5, new: [1.8] * 5})
    assert better(cv, new, old, cfg)
    k, path = choose_size(cv, [[(L_old, old)], [(0.9 * L_old, new)]], cfg)
    assert k == 1 and path[1]["accepted"] and path[1]["on_edge"] == [] and path[1]["margin"] > 0


def test_an_effect_the_held_out_part_does_not_support_is_not_named():
    rng = np.random.default_rng(0)
    y = rng.normal(0, 3, (500, 6))
    w = np.ones_like(y)
    resid = y * 0.5
    assert unsupported(["a", "b"], {"a": 0.3, "b": 0.2}, y, resid, w, 0.01, lambda rest: y) is None
    e, why = unsupported(["a", "b"], {"a": 0.3, "b": -0.002}, y, resid, w, 0.01, lambda rest: y)
    assert e == "b" and "-0.2 %" in why
    # an axis left worse than the nominal model by more than the noise floor's variance
    worse = resid.copy()
    worse[:, 2] = 2 * y[:, 2]
    e, why = unsupported(["a", "b"], {"a": 0.3, "b": 0.2}, y, worse, w, 0.01,
                         lambda rest: worse if "b" in rest else resid)
    assert e == "b" and "f_z" in why
    # 5 % worse, but by half the noise floor's variance (the weights' unit): regressor noise on an axis the
    # nominal model already fits to noise, kept
    slight = resid.copy()
    v = np.mean(y[:, 1] ** 2)
    slight[:, 1] = y[:, 1] * np.sqrt((v + 0.5) / v)
    assert unsupported(["a"], {"a": 0.3}, y, slight, w, 0.01, lambda rest: y) is None
    slight[:, 1] = y[:, 1] * np.sqrt((v + 1.5) / v)  # by 1.5 x that variance: not kept
    assert unsupported(["a"], {"a": 0.3}, y, slight, w, 0.01, lambda rest: y)[0] == "a"


def _stats(X, y, blocks=10):
    """Block statistics of a design ``X`` (N, 6, p) against labels ``y`` (N, 6), unit weights."""
    n = len(y)
    b = np.repeat(np.arange(blocks), n // blocks)
    G = np.stack([np.einsum("nri,nrj->ij", X[b == k], X[b == k]) for k in range(blocks)])
    h = np.stack([np.einsum("nri,nr->i", X[b == k], y[b == k]) for k in range(blocks)])
    s = np.array([np.sum(y[b == k] ** 2) for k in range(blocks)])
    cols = Columns.of(["mass_error", "body_force_bias"])
    return BlockStats(G, h, s, np.full(blocks, 6.0 * n / blocks), cols)


def test_two_effects_that_cancel_where_the_flight_spends_its_time_are_flagged():
    """A mass error against a body-z force: at hover both are constant along z and opposite; the fit
    makes both large, their sum small."""
    rng = np.random.default_rng(1)
    n = 2000
    g = 9.81 + rng.normal(0, 0.05, n)  # the mass error's regressor on z: nearly constant at hover
    X = np.zeros((n, 6, 4))
    X[:, 2, 0] = g
    X[:, 0, 1] = X[:, 1, 2] = X[:, 2, 3] = 1.0
    # truth: dm = 0.5 and bz = -4.9 cancel to the small variation 0.5 (g - 9.81); plus noise
    y = np.zeros((n, 6))
    y[:, 2] = 0.5 * g - 4.905 + rng.normal(0, 0.01, n)
    why = cancelling(_stats(X, y), ["mass_error", "body_force_bias"])
    assert why and "mass_error and body_force_bias cancel" in why
    # the same pair where they do not cancel (a body-x force beside a mass error): no flag
    y2 = np.zeros((n, 6))
    y2[:, 2] = 0.5 * g + rng.normal(0, 0.01, n)
    y2[:, 0] = 0.3
    assert cancelling(_stats(X, y2), ["mass_error", "body_force_bias"]) is None


def test_one_effect_cancels_nothing():
    X = np.ones((100, 6, 4))
    assert cancelling(_stats(X, np.ones((100, 6))), ["mass_error"]) is None
