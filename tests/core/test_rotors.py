import numpy as np
import pytest

CT, CQ, L = 4.9782e-8, 8.0e-10, 0.17


def test_plus_layout_is_thesis_eq_4_3(hummingbird):
    expected = np.array([[CT, CT, CT, CT],
                         [0, CT * L, 0, -CT * L],
                         [-CT * L, 0, CT * L, 0],
                         [-CQ, CQ, -CQ, CQ]])
    np.testing.assert_allclose(hummingbird.rotors.matrix, expected, rtol=1e-15)


def test_pure_roll_and_pure_yaw_by_hand(hummingbird):
    T, G = hummingbird.rotors.thrust_torque(np.array([[5900.0, 6000.0, 5900.0, 5800.0]]))
    # Γx = C_T l (6000² - 5800²) = 4.9782e-8 * 0.17 * 2.36e6
    assert G[0, 0] == pytest.approx(0.0199727, rel=1e-5)
    assert G[0, 1] == pytest.approx(0.0, abs=1e-12)
    assert G[0, 2] == pytest.approx(8e-10 * 0.02e6, rel=1e-9)
    T, G = hummingbird.rotors.thrust_torque(np.array([[5800.0, 6000.0, 5800.0, 6000.0]]))
    assert T[0] == pytest.approx(4.9782e-8 * 139.28e6, rel=1e-12)
    assert G[0, 2] == pytest.approx(3.776e-3, rel=1e-9)
    np.testing.assert_allclose(G[0, :2], 0.0, atol=1e-15)


def test_inverse_map_round_trip(hummingbird):
    u = np.array([[5000.0, 6200.0, 5500.0, 5900.0]])
    w = hummingbird.rotors.wrench(u)
    np.testing.assert_allclose(hummingbird.rotors.speeds_for(w[0]), u[0], rtol=1e-10)


def test_crazyflie_layout_is_the_sources_mixer(crazyflie):
    # SOURCE.md: B0 = [[1,1,1,1],[-a,-a,a,a],[-a,a,a,-a],[-t2t,t2t,-t2t,t2t]] on rotor forces f_i
    a = 0.707106781 * 0.046
    B0 = np.array([[1, 1, 1, 1], [-a, -a, a, a], [-a, a, a, -a], [-0.006, 0.006, -0.006, 0.006]])
    ct = 4.310657321921365e-08 * 9.81e-3
    np.testing.assert_allclose(crazyflie.rotors.matrix, B0 * ct, rtol=1e-5)
