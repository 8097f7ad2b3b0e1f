"""High-level controller: the LQR gain of thesis eq. 5.11 from the Riccati equation (eqs. 5.6-5.10)."""

import numpy as np
from scipy.linalg import solve_continuous_are

from qr.sim.control import Gains, controller_params, lqr_gain


def test_gain_equals_eq_5_11_to_4_decimals():
    K = lqr_gain(100.0, 10.0, 0.2)  # Q = diag(100 I, 10 I), R = 0.2 I (eq. 5.10)
    expected = np.hstack([22.3607 * np.eye(3), 9.7325 * np.eye(3)])  # eq. 5.11
    np.testing.assert_allclose(K, expected, atol=5e-5)
    # independent check: the scalar double integrator's closed form k_p = sqrt(q_p/r),
    # k_d = sqrt((q_v + 2 sqrt(q_p r)) / r)
    assert np.isclose(K[0, 0], np.sqrt(100 / 0.2)) and np.isclose(K[0, 3], np.sqrt((10 + 2 * np.sqrt(20)) / 0.2))


def test_gain_solves_the_riccati_equation_and_stabilises():
    A = np.block([[np.zeros((3, 3)), np.eye(3)], [np.zeros((3, 6))]])
    B = np.vstack([np.zeros((3, 3)), np.eye(3)])
    P = solve_continuous_are(A, B, np.diag([100.0] * 3 + [10.0] * 3), 0.2 * np.eye(3))
    np.testing.assert_allclose(lqr_gain(), B.T @ P / 0.2, rtol=1e-12)
    assert np.all(np.linalg.eigvals(A - B @ lqr_gain()).real < 0)


def test_controller_uses_the_thesis_gains_and_the_config(hummingbird):
    from qr.sim.simulation import simulate_config
    from qr.sim.specs import settings

    sim = simulate_config(["simulate=thesis"])
    C = controller_params(hummingbird, settings(sim).gains)
    np.testing.assert_allclose(C[20:26], [22.3607] * 3 + [9.7325] * 3, atol=5e-5)
    assert settings(sim).gains == Gains()
