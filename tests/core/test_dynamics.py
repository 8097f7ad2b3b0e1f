import numpy as np
import pytest

from qr import dynamics
from qr.frames import quat_to_rot


def _R(q):
    return quat_to_rot(np.atleast_2d(q))


def _residual_torque(alpha, omega, u, vehicle):
    """``τ_a`` (eq. 4.39) from arrays: J α minus the nominal torque of the rotor speeds ``u``."""
    _, Gamma = dynamics.thrust_torque(u, vehicle)
    return alpha * vehicle.inertia - dynamics.nominal_torque(omega, Gamma, vehicle.inertia)


def test_hover_has_zero_residual(hummingbird):
    u_h = np.sqrt(0.7 * 9.81 / (4 * 4.9782e-8))
    assert u_h == pytest.approx(5872.4, abs=0.1)
    u = np.full((1, 4), u_h)
    f = dynamics.residual_force(np.zeros((1, 3)), _R([1, 0, 0, 0]), u, hummingbird)
    np.testing.assert_allclose(f, 0.0, atol=1e-12)
    tau = _residual_torque(np.zeros((1, 3)), np.zeros((1, 3)), u, hummingbird)
    np.testing.assert_allclose(tau, 0.0, atol=1e-15)


def test_tilted_vehicle_at_rest_by_hand(hummingbird):
    # rolled 30°, held still (a = 0), rotors off: f_a = -m R^T g = m g [0, sin 30°, cos 30°]
    phi = np.radians(30)
    R = _R([np.cos(phi / 2), np.sin(phi / 2), 0, 0])
    f = dynamics.residual_force(np.zeros((1, 3)), R, np.zeros((1, 4)), hummingbird)
    np.testing.assert_allclose(f, [[0, 0.7 * 9.81 * 0.5, 0.7 * 9.81 * np.cos(phi)]], rtol=1e-12)


def test_pure_roll_torque_residual(hummingbird):
    u = np.array([[5900.0, 6000.0, 5900.0, 5800.0]])
    G = np.array([4.9782e-8 * 0.17 * 2.36e6, 0.0, 8e-10 * 0.02e6])
    # the angular acceleration the rotor torque explains leaves no residual ...
    tau = _residual_torque((G / np.array([0.007, 0.007, 0.012]))[None], np.zeros((1, 3)), u, hummingbird)
    np.testing.assert_allclose(tau, 0.0, atol=1e-8)
    # ... and a vehicle that does not accelerate shows -Γ
    tau = _residual_torque(np.zeros((1, 3)), np.zeros((1, 3)), u, hummingbird)
    np.testing.assert_allclose(tau, -G[None], rtol=1e-5)


def test_gyroscopic_term_by_hand(hummingbird):
    # J = diag(0.007, 0.007, 0.012), ω = [1, 0, 2]: (Jω) × ω = [0, 0.024 - 0.014, 0]
    tau = _residual_torque(np.zeros((1, 3)), np.array([[1.0, 0, 2.0]]), np.zeros((1, 4)), hummingbird)
    np.testing.assert_allclose(tau, [[0, -0.010, 0]], atol=1e-15)


def test_derivatives_agree_with_finite_differences_of_the_plant(hummingbird):
    from qr.sim.synth import SynthConfig, simulate_truth

    truth = simulate_truth(hummingbird, [], SynthConfig(duration=6, rate=500, seed=4, noise_free=True))
    q = truth[["qw", "qx", "qy", "qz"]].to_numpy()
    v = truth[["vx", "vy", "vz"]].to_numpy()
    w = truth[["wx", "wy", "wz"]].to_numpy()
    u = truth[["u1", "u2", "u3", "u4"]].to_numpy()
    p_dot, v_dot, q_dot, w_dot = dynamics.derivatives(truth[["px", "py", "pz"]].to_numpy(), v, q, w, u, hummingbird)
    h = 1 / 500
    fd = lambda x: (x[2:] - x[:-2]) / (2 * h)  # noqa: E731
    inner = slice(1, -1)
    for model, states in ((v_dot, v), (w_dot, w), (q_dot, q), (p_dot, truth[["px", "py", "pz"]].to_numpy())):
        err = np.abs(model[inner] - fd(states)).max()
        scale = np.abs(model).max()
        assert err < 2e-3 * scale, (err, scale)
