"""Stability analysis of thesis §5.3.1: M_{v,a} (eq. 5.15), its eigenvalues, and the closed loop they predict."""

import numpy as np
import pytest

from qr.sim.bezier import bezier_trajectory
from qr.sim.disturbance import LinearForce
from qr.sim.study import Plant, SimSettings, fly
from qr.sim.stability import analyse, eigenvalues, growth_per_step, m_va

M = 0.7
DT = 1e-3


def axis_roots(a: float, v: float, dt: float) -> np.ndarray:
    """The two eigenvalues of one axis with ``W_a/m = a``, ``W_v/m = v``: roots of (λ-1)(λ-a) - dt v."""
    return np.roots([1.0, -(1.0 + a), a - dt * v])


def _rot_block(re, im, zz):
    return np.array([[re, -im, 0.0], [im, re, 0.0], [0.0, 0.0, zz]])


def test_m_va_is_eq_5_15():
    Wv, Wa = np.arange(9.0).reshape(3, 3), -np.arange(9.0).reshape(3, 3)
    Mva = m_va(Wv, Wa, M, DT)
    np.testing.assert_array_equal(Mva[:3, :3], np.eye(3))
    np.testing.assert_array_equal(Mva[:3, 3:], DT * np.eye(3))
    np.testing.assert_allclose(Mva[3:, :3], Wv / M)
    np.testing.assert_allclose(Mva[3:, 3:], Wa / M)


def test_axis_by_axis_model_has_the_quadratic_roots():
    """Diagonal W_v, W_a: per axis det = (λ-1)(λ-a) - dt v, so the roots are known in closed form."""
    a = np.array([0.4, -1.3, 1.2])
    v = np.array([-50.0, 20.0, 300.0])
    lam = eigenvalues(np.diag(M * v), np.diag(M * a), M, DT)
    expected = np.concatenate([axis_roots(ai, vi, DT) for ai, vi in zip(a, v)])
    assert np.allclose(np.sort_complex(lam), np.sort_complex(expected), atol=1e-12)
    # by hand for the first axis: λ² - 1.4 λ + (0.4 + 0.05) = 0
    np.testing.assert_allclose(np.sort(axis_roots(0.4, -50.0, DT)), [0.5, 0.9])


def test_eq_5_16_pattern_from_a_hand_made_model():
    """W_v = 0 and W_a/m = a rotation-scaled block: eig = {1, 1, 1} ∪ eig(W_a/m), two complex above 1."""
    Wa = M * _rot_block(1.5810, 0.1377, 1.0017)
    an = analyse(np.zeros((3, 3)), Wa, M, DT)
    lam = an.eigenvalues
    np.testing.assert_allclose(lam[:2], [1.5810 - 0.1377j, 1.5810 + 0.1377j], atol=1e-12)
    np.testing.assert_allclose(lam[2:], [1.0017, 1.0, 1.0, 1.0], atol=1e-7)  # one eigenvalue of 1 is triple
    assert an.n_above_one == 3 and an.lagged_prediction == "diverges"
    assert an.max_abs_eig == pytest.approx(np.hypot(1.5810, 0.1377))
    assert an.implicit_prediction == "unstable"  # m I - W_a has negative eigenvalues: negative mass


def test_implicit_reading_separates_the_lag_artefact_and_the_leak():
    flip = analyse(np.zeros((3, 3)), -1.3 * M * np.eye(3), M, DT)
    assert flip.lagged_prediction == "diverges" and flip.implicit_prediction == "stable"
    leak = analyse(np.zeros((3, 3)), M * np.eye(3), M, DT)  # W_a = m I: the label identity of eq. 4.34
    assert leak.lagged_prediction == "bounded" and leak.implicit_prediction == "ill-posed"
    small = analyse(np.diag([-0.2, -0.2, -0.1]), 0.3 * M * np.eye(3), M, DT)
    assert small.n_above_one == 0 and small.implicit_prediction == "stable"


@pytest.fixture(scope="module")
def short_traj():
    return bezier_trajectory()


def _model(Wa):
    return LinearForce(np.hstack([np.zeros((3, 3)), Wa]), np.zeros(3), ("v_b", "a_b"), "hand")


def test_closed_loop_diverges_as_predicted_and_stops_with_a_message(hummingbird, short_traj):
    Wa = hummingbird.mass * _rot_block(1.5810, 0.1377, 1.0017)
    lam = analyse(np.zeros((3, 3)), Wa, hummingbird.mass, DT).max_abs_eig
    res = fly(short_traj, Plant(hummingbird, [], _model(Wa), "lagged"), None, SimSettings(log_rate=1000.0))
    assert res.status == "diverged" and res.t_end < 0.2
    assert res.message.startswith("diverged at t = ") and "stopped and recorded" in res.message
    m = res.metrics()
    assert m["status"] == "diverged" and all(np.isfinite(v) for v in m.values() if isinstance(v, float))
    assert np.isfinite(res.log.to_numpy()).all()
    growth = growth_per_step(res.log[["f_true_x", "f_true_y", "f_true_z"]].to_numpy())
    assert growth == pytest.approx(lam, rel=0.05)  # the per-step growth the eigenvalue predicts


def test_lag_artefact_diverges_while_the_implicit_plant_flies(hummingbird, short_traj):
    Wa = -1.3 * hummingbird.mass * np.eye(3)
    cfg = SimSettings(duration=3.0)
    lagged = fly(short_traj, Plant(hummingbird, [], _model(Wa), "lagged"), None, cfg)
    implicit = fly(short_traj, Plant(hummingbird, [], _model(Wa), "implicit"), None, cfg)
    assert lagged.diverged and not implicit.diverged
    assert implicit.metrics()["rmse"] < 0.05
