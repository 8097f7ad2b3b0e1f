"""Closed-loop study: nominal vs compensated vs oracle, against independent expectations."""

import numpy as np
import pandas as pd
import pytest

from qr.effects import parse_effect_spec
from qr.sim.bezier import bezier_trajectory
from qr.sim.control import lqr_gain
from qr.sim.disturbance import CatalogForce, fit_effects, thesis_model8
from qr.sim.study import ORACLE, Plant, Reference, SimSettings, fly, identification_data

DRAG_WIND = [parse_effect_spec("linear_drag:kx=0.3,ky=0.3,kz=0.1"),
             parse_effect_spec("wind_force:fx=0.4,fy=-0.3,fz=-0.2")]


def _hover(p=(0.0, 0.0, 1.0), duration=6.0):
    p = np.array(p, dtype=float)
    return Reference(lambda t: (p, np.zeros(3), np.zeros(3), 0.0, 0.0), duration)


def test_steady_offset_under_a_constant_wind_is_f_over_m_kp(hummingbird):
    """Independent expectation: at hover a world force f leaves the LQR an offset f / (m k_p)."""
    wind = [parse_effect_spec("wind_force:fx=0.5,fy=-0.25,fz=0")]
    kp = lqr_gain()[0, 0]
    res = fly(_hover(), Plant(hummingbird, wind), None)
    end = res.log.iloc[-1]
    assert end["px"] == pytest.approx(0.5 / (hummingbird.mass * kp), rel=0.02)
    assert end["py"] - 0.0 == pytest.approx(-0.25 / (hummingbird.mass * kp), rel=0.02)
    comp = fly(_hover(), Plant(hummingbird, wind), CatalogForce(wind, hummingbird))
    assert abs(comp.log.iloc[-1]["px"]) < 1e-4  # the compensation cancels it (sign convention)


def test_oracle_knows_the_true_force(hummingbird):
    """The oracle's estimate is the catalog term of the hidden effects (two independent derivations)."""
    from qr.states import signals

    res = fly(bezier_trajectory(), Plant(hummingbird, DRAG_WIND), ORACLE, SimSettings(duration=5.0))
    s = signals(res.log)
    expected = CatalogForce(DRAG_WIND, hummingbird).predict(s)
    np.testing.assert_allclose(res.log[["f_est_x", "f_est_y", "f_est_z"]].to_numpy(), expected, atol=1e-9)


def test_compensation_with_an_identified_model_halves_the_error_and_nears_the_oracle(hummingbird):
    """Done-when: linear drag + wind; the estimate is identified on another (random) flight with noisy labels."""
    plant = Plant(hummingbird, DRAG_WIND)
    s, f_a = identification_data(plant, duration=30.0, seed=3, accel_noise=0.1)
    est = fit_effects(s, f_a, ["linear_drag", "wind_force"], hummingbird)
    k = est.effects[0]["parameters"]
    assert k["kx"] == pytest.approx(0.3, rel=0.05)  # identified, not copied
    cfg = SimSettings(duration=12.0)
    traj = bezier_trajectory()
    rmse = {name: fly(traj, plant, e, cfg).metrics()["rmse"]
            for name, e in [("nominal", None), ("compensated", est), ("oracle", ORACLE)]}
    assert rmse["compensated"] <= 0.5 * rmse["nominal"]
    assert rmse["compensated"] <= 1.2 * rmse["oracle"]
    assert rmse["nominal"] > 0.01  # the disturbance matters at all


def test_thesis_model8_is_eq_4_38_and_compensates_its_own_disturbance(hummingbird):
    m8 = thesis_model8()
    assert m8.W.shape == (3, 7) and m8.inputs == ("v_b", "u")
    assert m8.W[1, 1] == -0.4139 and m8.W[2, 6] == -0.2713 and list(m8.b) == [0.4768, 0.2994, -0.3817]
    from qr.effects import Signals
    u = np.full((1, 4), 6000.0)
    s = Signals(np.eye(3)[None], np.array([[1.0, 0.0, 0.0]]), np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)),
                u, np.zeros((1, 4)), np.zeros((1, 3)))
    expected = m8.W @ np.concatenate([[1.0, 0.0, 0.0], u[0] / 1e4]) + m8.b
    np.testing.assert_allclose(m8.predict(s)[0], expected)
    cfg = SimSettings(duration=8.0)
    traj = bezier_trajectory()
    nom = fly(traj, Plant(hummingbird, force=m8), None, cfg).metrics()
    comp = fly(traj, Plant(hummingbird, force=m8), m8, cfg).metrics()
    assert comp["rmse"] < 0.2 * nom["rmse"]


def test_divergence_ends_the_run_with_a_recorded_row(hummingbird):
    """A disturbance the vehicle cannot carry: the study stops the run and records it, no NaN, no hang."""
    from qr.sim.simulation import tracking_study

    force = {"model": "linear", "inputs": ["v_b"], "W": np.zeros((3, 3)).tolist(), "b": [0.0, 0.0, -40.0]}
    sim = {"vehicle": "asctec_hummingbird", "rate": 500, "duration": 6.0,
           "sources": {"too_heavy": {"plant": {"force": force}, "estimates": {}}}}
    table = tracking_study(sim, progress=False).table
    assert set(table["status"]) == {"diverged"}
    row = table.iloc[0]
    assert row["message"].startswith("diverged at t = ") and "position error" in row["message"]
    assert 0 < row["t_end_s"] < 6.0
    assert not table.select_dtypes("number").isna().any().any()


def test_same_config_same_numbers(hummingbird):
    from qr.sim.simulation import tracking_study

    sim = {"vehicle": "asctec_hummingbird", "duration": 3.0, "identification": {"duration_s": 10.0, "seed": 1,
                                                                               "accel_noise_m_s2": 0.1},
           "sources": {"dw": {"plant": {"effects": ["wind_force:fx=0.3,fy=0,fz=0"]},
                              "estimates": {"fit": {"model": "fit_linear", "inputs": ["v_b", "u"]}}}}}
    a = tracking_study(sim, progress=False).table
    b = tracking_study(sim, progress=False).table
    pd.testing.assert_frame_equal(a, b)
    assert list(a["controller"]) == ["nominal", "compensated:fit", "oracle"]
    assert a.loc[a["controller"] == "oracle", "ratio_to_oracle"].item() == 1.0


def test_a_leaking_model_is_refused_for_tracking(hummingbird):
    from qr.errors import QrInputError
    from qr.sim.simulation import tracking_study

    leaky = {"model": "linear", "inputs": ["a_b"], "W": np.eye(3).tolist(), "b": [0, 0, 0]}
    sim = {"vehicle": "asctec_hummingbird", "duration": 1.0,
           "sources": {"x": {"plant": {"effects": []}, "estimates": {"leaky": leaky}}}}
    with pytest.raises(QrInputError, match="leaks the target"):
        tracking_study(sim, progress=False)
