"""Reference trajectory of thesis eqs. 5.3-5.5: a correct cubic Bezier through waypoints and tangents."""

import numpy as np
import pytest

from qr.errors import QrInputError
from qr.sim.bezier import THESIS_TANGENTS, THESIS_WAYPOINTS, bezier_trajectory, control_points, from_config

T = 5.0


@pytest.fixture(scope="module")
def traj():
    return bezier_trajectory(segment_duration_s=T)


def test_eq_5_3_and_control_points_eq_5_4():
    assert THESIS_WAYPOINTS.shape == (6, 3)
    np.testing.assert_array_equal(THESIS_WAYPOINTS[2], [0, 2, 1])
    np.testing.assert_array_equal(THESIS_TANGENTS[0], [0, 0, 0.5])
    c = control_points(THESIS_WAYPOINTS, THESIS_TANGENTS)
    assert c.shape == (5, 4, 3)
    k = 2
    np.testing.assert_array_equal(c[k, 1], THESIS_WAYPOINTS[k] + THESIS_TANGENTS[k])  # p1 = p_start + v_start
    np.testing.assert_array_equal(c[k, 2], THESIS_WAYPOINTS[k + 1] - THESIS_TANGENTS[k + 1])  # p2 = p_end - v_end


def test_weights_are_the_binomial_bernstein_ones_not_eq_5_5(traj):
    """Inside each segment the trajectory is the Bernstein form (weights summing to one) of its control
    points; eq. 5.5's weights (without the binomial 3s) would lose half the curve at s = 1/2."""
    s = np.linspace(0, 1, 11)
    bernstein = np.stack([(1 - s) ** 3, 3 * (1 - s) ** 2 * s, 3 * (1 - s) * s**2, s**3], axis=1)
    np.testing.assert_allclose(bernstein.sum(axis=1), 1.0)
    c = control_points(THESIS_WAYPOINTS, THESIS_TANGENTS)
    for k in range(len(c)):
        got = np.array([traj.at(k * T + si * T)[0] for si in s[1:-1]])
        np.testing.assert_allclose(got, bernstein[1:-1] @ c[k], atol=1e-12)
    eq_5_5 = np.stack([(1 - s) ** 3, (1 - s) ** 2 * s, (1 - s) * s**2, s**3], axis=1)
    assert eq_5_5.sum(axis=1)[5] == pytest.approx(0.5)


def test_passes_through_the_waypoints_with_the_given_tangents(traj):
    for k, (p, v) in enumerate(zip(THESIS_WAYPOINTS, THESIS_TANGENTS)):
        t = k * T
        np.testing.assert_allclose(traj.at(t)[0], p, atol=1e-12)
        # B'(0) = 3 (P1 - P0) = 3 v_k per unit curve parameter, s = t / T: velocity 3 v_k / T,
        # from the segment before and after the waypoint (C1 chain)
        for tt in ([t - 1e-9] if k else []) + ([t + 1e-9] if k < 5 else []):
            np.testing.assert_allclose(traj.at(tt)[1], 3 * v / T, atol=1e-7)


def test_velocity_and_acceleration_are_the_derivatives(traj):
    t = np.linspace(0.3, 24.7, 400)
    t = t[np.min(np.abs(t[:, None] - T * np.arange(6)), axis=1) > 0.01]  # acceleration jumps at waypoints
    h = 1e-5
    for ti in t:
        p0, v0, a0, _, _ = traj.at(ti)
        p1, v1, _, _, _ = traj.at(ti + h)
        pm, vm, _, _, _ = traj.at(ti - h)
        np.testing.assert_allclose((p1 - pm) / (2 * h), v0, atol=1e-7)
        np.testing.assert_allclose((v1 - vm) / (2 * h), a0, atol=1e-6)


def test_yaw_is_the_heading_with_its_rate(traj):
    t = np.linspace(0.05, 24.95, 300)
    rows = [traj.at(ti) for ti in t]
    v = np.array([r[1] for r in rows])
    yaw = np.array([r[3] for r in rows])
    np.testing.assert_allclose(np.cos(yaw), v[:, 0] / np.hypot(v[:, 0], v[:, 1]), atol=1e-9)
    np.testing.assert_allclose(np.sin(yaw), v[:, 1] / np.hypot(v[:, 0], v[:, 1]), atol=1e-9)
    assert np.all(np.abs(np.diff(yaw)) < 0.2)  # unwrapped: no 2 pi jumps
    ti = 7.3
    h = 1e-5
    assert (traj.at(ti + h)[3] - traj.at(ti - h)[3]) / (2 * h) == pytest.approx(traj.at(ti)[4], abs=1e-6)


def test_table_has_1000_points_per_segment_and_time_scaling(traj):
    df = traj.sample(1000)
    assert len(df) == 5 * 1000 + 1 and df["t"].iloc[-1] == 25.0
    slow = bezier_trajectory(segment_duration_s=2 * T)
    assert slow.duration == 50.0
    np.testing.assert_allclose(slow.at(2 * 7.0)[0], traj.at(7.0)[0])
    np.testing.assert_allclose(slow.at(2 * 7.0)[1], traj.at(7.0)[1] / 2)
    np.testing.assert_allclose(slow.at(2 * 7.0)[2], traj.at(7.0)[2] / 4)
    fixed = from_config({"yaw": "fixed", "yaw0": 0.3})
    assert fixed.at(3.0)[3:] == (0.3, 0.0)


def test_bad_trajectory_config_is_one_clear_error():
    with pytest.raises(QrInputError, match="yaw mode"):
        from_config({"yaw": "sideways"})
    with pytest.raises(QrInputError, match="positive"):
        from_config({"segment_duration_s": 0})
    with pytest.raises(QrInputError, match="do not match"):
        from_config({"waypoints": [[0, 1], [0, 1], [0, 1]]})
