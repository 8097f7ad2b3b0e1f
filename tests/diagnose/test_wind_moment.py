"""A steady wind's moment is not named a CG offset (qr.diagnose.wind).

The mechanism first, in an independent simulator: RotorPy's Hummingbird (its aerodynamics act on the
airspeed, its rotors flap: k_flap = -1e-5, as tests/export/test_rotorpy_diagnosis.py) flies its circles in a
steady wind.  The wind's drag is a force constant in the world frame (``wind_force``); its flapping is a
moment nearly constant in the body frame at the held heading, which ``cg_offset`` fits to a fraction of a
millimetre.  That CG offset must come with ``confounded_with: ["wind_force"]`` and the numbers.

The rule costs nothing where the moment is not the wind's: qr's own simulator with a real CG offset whose
moment is square to the wind's (the same named set) keeps cg_offset unconfounded.  And its geometry is
checked by hand on signals made for it.
"""

import numpy as np
import pytest

from qr.diagnose.wind import MAX_ANGLE_DEG, wind_moments
from qr.effects import Signals
from qr.identification.normal_equations import Columns
from qr.sim.scenarios import Scenario, diagnose_scenario
from qr.vehicle import load_vehicle

WIND = (1.5, -1.0, 0.0)  # m/s, world


def test_a_cg_moment_along_the_winds_is_reported_as_possibly_the_winds_by_hand():
    """Level flight, heading held: the wind the named force implies is f / k per axis, its flapping moment
    k_f [-w_y, w_x], a CG offset's [-ry T, rx T] (T the rotor map's thrust): flagged when they agree within the
    rule's angle and factor, not when they are square to each other."""
    vehicle = load_vehicle("crazyflie21_brushless")
    n = 400
    rng = np.random.default_rng(0)
    R = np.repeat(np.eye(3)[None], n, 0)
    u = np.full((n, 4), vehicle.hover_speed)
    z = np.zeros((n, 3))
    s = Signals(R, rng.normal(0, 1, (n, 3)), z, z, z, u, np.zeros((n, 4)), z)
    T = float(vehicle.rotors.matrix[0] @ u[0] ** 2)
    k, kf, f = 0.02, 1e-3, np.array([0.03, -0.02, 0.0])
    w = f[:2] / k  # (1.5, -1.0) m/s
    tau_wind = kf * np.array([-w[1], w[0]])
    named = ["linear_drag", "wind_force", "cg_offset", "blade_flapping"]
    cols = Columns.of(named)

    def theta(rx, ry):
        th = np.zeros(cols.size)
        th[cols.slices["linear_drag"]] = k
        th[cols.slices["wind_force"]] = f
        th[cols.slices["cg_offset"]] = rx, ry
        th[cols.slices["blade_flapping"]] = kf
        return th

    rx, ry = tau_wind[1] / T * 1.2, -tau_wind[0] / T * 1.2  # the wind's moment, 1.2 x
    (m,) = wind_moments(s, vehicle, named, theta(rx, ry))
    assert m.effect == "cg_offset"
    np.testing.assert_allclose(m.wind, w, rtol=1e-9)
    np.testing.assert_allclose(m.wind_moment, tau_wind, rtol=1e-9)
    np.testing.assert_allclose(m.named_moment, 1.2 * tau_wind, rtol=1e-9)
    assert m.angle_deg == pytest.approx(0, abs=1e-5) and m.ratio == pytest.approx(1.2)
    # square to the wind's moment, or 4 x its size: the wind could not make it
    square = np.array([tau_wind[1], -tau_wind[0]])
    assert wind_moments(s, vehicle, named, theta(square[1] / T, -square[0] / T)) == ()
    assert wind_moments(s, vehicle, named, theta(4 * tau_wind[1] / T, -4 * tau_wind[0] / T)) == ()
    # at 45 degrees (beyond the rule's angle) neither
    c, sn = np.cos(np.radians(MAX_ANGLE_DEG + 15)), np.sin(np.radians(MAX_ANGLE_DEG + 15))
    turned = np.array([[c, -sn], [sn, c]]) @ tau_wind
    assert wind_moments(s, vehicle, named, theta(turned[1] / T, -turned[0] / T)) == ()
    # without a drag named no wind can be inferred; without a velocity moment the wind makes none
    assert wind_moments(s, vehicle, ["wind_force", "cg_offset", "blade_flapping"],
                        np.r_[f, rx, ry, kf]) == ()
    assert wind_moments(s, vehicle, ["linear_drag", "wind_force", "cg_offset"], np.r_[k, k, k, f, rx, ry]) == ()


def test_the_winds_moment_in_rotorpy_is_not_named_a_cg_offset(tmp_path):
    pytest.importorskip("rotorpy")
    from rotorpy_cases import diagnose_circles, hummingbird

    doc = diagnose_circles(hummingbird(), tmp_path, wind=WIND)
    named = {e["name"]: e for e in doc["effects"]}
    assert "wind_force" in named, list(named)
    # the wind's force points along the wind (RotorPy's drag on the airspeed v - w)
    f = np.array([named["wind_force"]["parameters"][p] for p in ("fx", "fy")])
    assert f @ np.array(WIND[:2]) / (np.linalg.norm(f) * np.linalg.norm(WIND[:2])) > np.cos(np.radians(30))
    constant = [e for e in ("cg_offset", "torque_bias") if e in named]
    assert constant, list(named)  # the wind's moment is there to be fitted
    for e in constant:
        assert "wind_force" in named[e]["confounded_with"], named[e]
    said = {m["effect"]: m for m in doc["wind_moment"]}
    assert set(said) == set(constant)
    for m in said.values():  # the wind it infers points along the true one
        w = np.array(m["wind"])
        assert w @ np.array(WIND[:2]) / (np.linalg.norm(w) * np.linalg.norm(WIND[:2])) > np.cos(np.radians(30))
    report = (tmp_path / "diag" / "report.md").read_text()
    assert "it may be the wind's moment" in report and "it may be the wind's moment" in doc["verdict"]
    assert doc["vehicle_file"] == []


def test_a_real_cg_offset_square_to_the_winds_moment_stays_a_cg_offset(tmp_path):
    """qr's own simulator: a CG offset (roll moment) beside a wind force along x, a linear drag and blade
    flapping (whose wind moment would pitch): cg_offset named, not confounded with the wind."""
    effects = [{"name": "linear_drag", "parameters": {"kx": 0.02, "ky": 0.02, "kz": 0.02}},
               {"name": "wind_force", "parameters": {"fx": 0.02, "fy": 0.0, "fz": 0.0}},
               {"name": "blade_flapping", "parameters": {"k": 0.001}},
               {"name": "cg_offset", "parameters": {"rx": 0.0, "ry": 0.002}}]
    sc = Scenario(seed=5, effects=effects, vehicle="crazyflie21_brushless", noise_scale=1.0, tilt_max_deg=20,
                  v_max=1.5)
    doc = diagnose_scenario(sc, tmp_path)
    named = {e["name"]: e for e in doc["effects"]}
    assert {"wind_force", "blade_flapping", "cg_offset"} <= set(named), list(named)
    assert "wind_force" not in named["cg_offset"]["confounded_with"]
    assert "wind_moment" not in doc
    assert named["cg_offset"]["parameters"]["ry"] == pytest.approx(0.002, rel=0.2)
