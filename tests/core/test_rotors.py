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
    """The wrench is the matrix times u², and the matrix is invertible: the speeds come back from it."""
    u = np.array([[5000.0, 6200.0, 5500.0, 5900.0]])
    w = hummingbird.rotors.wrench(u)
    np.testing.assert_allclose(np.sqrt(np.linalg.solve(hummingbird.rotors.matrix, w[0])), u[0], rtol=1e-10)


def test_crazyflie_layout_is_the_sources_mixer(crazyflie):
    # SOURCE.md: B0 = [[1,1,1,1],[-a,-a,a,a],[-a,a,a,-a],[-t2t,t2t,-t2t,t2t]] on rotor forces f_i
    a = 0.707106781 * 0.046
    B0 = np.array([[1, 1, 1, 1], [-a, -a, a, a], [-a, a, a, -a], [-0.006, 0.006, -0.006, 0.006]])
    ct = 4.310657321921365e-08 * 9.81e-3
    np.testing.assert_allclose(crazyflie.rotors.matrix, B0 * ct, rtol=1e-5)


def _x_vehicle(tmp_path, base, drop=(), **changes):
    import yaml

    from qr.vehicle import load_vehicle

    raw = yaml.safe_load(base.read_text())
    raw.update(layout="x", **changes)
    for k in drop:
        raw.pop(k)
    path = tmp_path / "x.yaml"
    path.write_text(yaml.safe_dump(raw))
    return load_vehicle(path)


def test_x_layout_by_hand(tmp_path):
    """``layout: x``: rotor 1 front-right, then counter-clockwise seen from above, at a = l/√2 on each
    axis; yaw signs as plus (the diagonal pairs 1-3 and 2-4 turn alike)."""
    from conftest import VEHICLES

    v = _x_vehicle(tmp_path, VEHICLES / "asctec_hummingbird.yaml")
    a = 0.1202081528  # 0.17 m / √2
    np.testing.assert_allclose(v.rotors.positions, [[a, -a], [a, a], [-a, a], [-a, -a]], rtol=1e-10)
    expected = np.array([[CT, CT, CT, CT],
                         [-CT * a, CT * a, CT * a, -CT * a],
                         [-CT * a, -CT * a, CT * a, CT * a],
                         [-CQ, CQ, -CQ, CQ]])
    np.testing.assert_allclose(v.rotors.matrix, expected, rtol=1e-10)
    # the left pair (2, 3) faster: a pure roll, left side up; Γx = C_T a · 2 (6000² − 5900²)
    T, G = v.rotors.thrust_torque(np.array([[5900.0, 6000.0, 6000.0, 5900.0]]))
    assert G[0, 0] == pytest.approx(4.9782e-8 * a * 2.38e6, rel=1e-10)  # 0.0142424 N m
    np.testing.assert_allclose(G[0, 1:], 0.0, atol=1e-15)
    # the back pair (3, 4) faster: a pure pitch, nose down (positive about body y)
    T, G = v.rotors.thrust_torque(np.array([[5900.0, 5900.0, 6000.0, 6000.0]]))
    assert G[0, 1] == pytest.approx(0.0142424, rel=1e-5)
    np.testing.assert_allclose(G[0, [0, 2]], 0.0, atol=1e-15)


def test_x_layout_is_the_plus_layout_turned_45_degrees(tmp_path, hummingbird):
    """Same speeds, same thrust and yaw torque; the roll/pitch torque turned by −45° about body z."""
    from conftest import VEHICLES

    v = _x_vehicle(tmp_path, VEHICLES / "asctec_hummingbird.yaml")
    u = np.random.default_rng(0).uniform(4000, 8000, (50, 4))
    Tp, Gp = hummingbird.rotors.thrust_torque(u)
    Tx, Gx = v.rotors.thrust_torque(u)
    c = s = np.sqrt(0.5)
    turn = np.array([[c, s], [-s, c]])  # rotation by −45°
    np.testing.assert_allclose(Tx, Tp, rtol=1e-14)
    np.testing.assert_allclose(Gx[:, 2], Gp[:, 2], rtol=1e-14)
    np.testing.assert_allclose(Gx[:, :2], Gp[:, :2] @ turn.T, rtol=1e-10, atol=1e-18)


def test_the_crazyflie_is_layout_x_numbered_clockwise(tmp_path, crazyflie):
    """The source's mixer (its own file, explicit) is layout x with rotors 2 and 4 swapped."""
    from conftest import VEHICLES

    v = _x_vehicle(tmp_path, VEHICLES / "crazyflie21_brushless.yaml", arm_length=0.046)
    # (the file quotes the arm 0.046 / √2 as 0.0325269: to 4e-7)
    np.testing.assert_allclose(v.rotors.matrix[:, [0, 3, 2, 1]], crazyflie.rotors.matrix, rtol=1e-6)


def test_layout_x_needs_the_arm_length(tmp_path):
    from conftest import VEHICLES
    from qr.errors import QrInputError

    with pytest.raises(QrInputError, match="lacks key\\(s\\) 'arm_length'"):
        _x_vehicle(tmp_path, VEHICLES / "crazyflie21_brushless.yaml", drop=["arm_length"])
