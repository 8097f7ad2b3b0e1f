"""The controller interface (qr.replay.controller.Controller): RotorPy's SE3Control flown through it by qr's
replay agrees with RotorPy's own simulator under the same controller; a user's class (MODULE:CLASS) flies
through the generic loop with the same numbers as the built-in compiled one."""

import numpy as np
import pytest

from conftest import DATA, VEHICLES

FIGURE8 = DATA.parent / "crazyswarm2-figure8" / "figure8.csv"
pytestmark = pytest.mark.skipif(not FIGURE8.exists(), reason="no figure-8 trajectory beside the data")


def _setpoints(timescale=1.0, start=0.2):
    from qr.replay.setpoints import Setpoints, read_pieces

    return Setpoints(read_pieces(FIGURE8), timescale, start, (0.0, 0.0, 1.0))


def test_rotorpy_se3_through_the_interface_flies_as_in_rotorpy():
    """1.2 s of the figure-8 (timescale 1.0, from hover) under RotorPy's SE3Control at 1 kHz: qr's replay (the
    adapter, qr's ideal mixer and plant, RK4 at 1 ms) and RotorPy's Multirotor (its own allocation and
    motors, DOP853 at rtol 1e-9) stay within 1e-7 of how far the vehicle moved (measured: 4e-11 over 2 s)."""
    pytest.importorskip("rotorpy")
    from rotorpy.controllers.quadrotor_control import SE3Control
    from rotorpy.vehicles.multirotor import Multirotor

    from qr.export import mapping
    from qr.export.rotorpy import quad_params
    from qr.replay.fly import fly, initial_state
    from qr.replay.rotorpy_controller import RotorPySE3
    from qr.vehicle import load_vehicle

    vehicle = load_vehicle(VEHICLES / "crazyflie21_brushless.yaml")
    sp = _setpoints()
    T, dt = 1.2, 1e-3
    x0 = initial_state(vehicle, np.array([0.0, 0.0, 1.0]), np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3),
                       np.full(4, vehicle.hover_speed))
    ours = fly(vehicle, RotorPySE3(rate_hz=1000.0), sp, x0, 0.0, T, vehicle.mass, sim_rate_hz=1000.0)

    params = quad_params(mapping.plant_of(vehicle))
    params = {**params, "rotor_pos": {k: np.asarray(v) for k, v in params["rotor_pos"].items()},
              "rotor_directions": np.asarray(params["rotor_directions"]), "rI": np.asarray(params["rI"])}
    unit = mapping.rad_s_per_unit(vehicle)
    state = {"x": np.array([0.0, 0.0, 1.0]), "v": np.zeros(3), "q": np.array([0.0, 0.0, 0.0, 1.0]), "w": np.zeros(3),
             "wind": np.zeros(3), "rotor_speeds": np.full(4, vehicle.hover_speed * unit)}
    quad = Multirotor(params, initial_state=state, aero=False,
                      integrator_kwargs={"method": "DOP853", "rtol": 1e-9, "atol": 1e-11})
    ctrl = SE3Control(params)
    n = int(round(T / dt))
    theirs = [state["x"].copy()]
    ref = sp.at(dt * np.arange(n))
    for k in range(n):
        flat = {"x": ref["p"][k], "x_dot": ref["v"][k], "x_ddot": ref["a"][k], "x_dddot": ref["j"][k],
                "x_ddddot": ref["s"][k], "yaw": ref["yaw"][k], "yaw_dot": ref["yaw_rate"][k], "yaw_ddot": 0.0}
        state = quad.step(state, ctrl.update(k * dt, state, flat), dt)
        theirs.append(state["x"].copy())
    theirs = np.array(theirs)
    moved = np.max(np.linalg.norm(theirs - theirs[0], axis=1))
    err = np.max(np.linalg.norm(ours.p[: n + 1] - theirs, axis=1))
    assert moved > 0.2 and err < 1e-7 * moved, f"qr vs RotorPy: {err:.3g} m of {moved:.3g} m moved"


class PythonLee:
    """A user's controller: the firmware's Lee controller, called through the interface (not compiled)."""

    name, rate_hz = "python_lee", 500.0

    def __init__(self):
        from qr.replay.lee import LeeController

        self.inner = LeeController()

    def reset(self, vehicle, mass):
        self.inner.reset(vehicle, mass)

    def __call__(self, t, state, setpoint):
        return self.inner(t, state, setpoint)

    def describe(self):
        return {"name": self.name, "rate_hz": self.rate_hz}


def test_a_users_controller_flies_through_the_generic_loop_as_the_compiled_one(crazyflie):
    """The Lee controller as a user's class (Python loop) and built in (compiled loop), one vehicle with a
    hidden drag, the same numbers."""
    from qr.replay.registry import controller_named
    from qr.replay.fly import fly, initial_state
    from qr.replay.lee import LeeController

    import sys
    sys.modules.setdefault("replay_user_module", sys.modules[__name__])
    vehicle = crazyflie.with_changes(effects=[{"name": "linear_drag", "parameters": {"kx": 0.02, "ky": 0.02, "kz": 0.01}}])
    x0 = initial_state(vehicle, np.array([0.0, 0.0, 1.0]), np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3),
                       np.full(4, vehicle.hover_speed))
    sp = _setpoints(0.8)
    a = fly(vehicle, LeeController(), sp, x0, 0.0, 3.0, 0.037)
    b = fly(vehicle, controller_named("replay_user_module:PythonLee"), sp, x0, 0.0, 3.0, 0.037)
    assert np.max(np.abs(a.p - sp.at(a.t, order=0)["p"])) > 0.01  # it flew the trajectory, with a tracking error
    np.testing.assert_allclose(b.x, a.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(b.thrust_cmd, a.thrust_cmd, rtol=0, atol=1e-15)


def test_a_model_whose_delay_is_shorter_than_the_step_flies_with_a_finer_step(crazyflie):
    """A refined model's actuator delay of 0.42 ms (below the replay's 1 ms step; a full workflow run wrote one):
    the replay integrates at the lowest multiple of the controller's 500 Hz whose step is at most the delay
    (2500 Hz, 0.4 ms), and the delay changes the flight by little (a 0.42 ms lag on a 10 Hz loop): within 1 mm
    of the same vehicle without it."""
    from qr.replay.fly import fly, initial_state, integration_rate
    from qr.replay.lee import LeeController

    assert integration_rate(1000.0, 500.0, 0.00042) == 2500.0  # 1/2500 = 0.4 ms ≤ 0.42 ms < 1/2000
    assert integration_rate(1000.0, 500.0, 0.0) == 1000.0 and integration_rate(1000.0, 500.0, 0.02) == 1000.0
    delayed = crazyflie.with_changes(effects=[{"name": "actuator_delay", "parameters": {"delay_s": 0.00042}}])
    x0 = initial_state(crazyflie, np.array([0.0, 0.0, 1.0]), np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3),
                       np.full(4, crazyflie.hover_speed))
    sp = _setpoints(0.8)
    a = fly(delayed, LeeController(), sp, x0, 0.0, 2.0, 0.037)
    b = fly(crazyflie, LeeController(), sp, x0, 0.0, 2.0, 0.037)
    assert a.t[1] - a.t[0] == pytest.approx(0.0004) and b.t[1] - b.t[0] == pytest.approx(0.001)
    on_b = np.stack([np.interp(b.t, a.t, a.p[:, i]) for i in range(3)], axis=1)
    assert np.max(np.abs(on_b - b.p)) < 1e-3


def test_replay_json_records_each_controllers_description_as_given(crazyflie):
    """The Replay's typed record of a controller (name, rate, gains) gives back the description it was made of:
    the Lee controller's (its gains, the mass it was told) and a user's without gains."""
    from qr.replay.controller import ControllerRecord
    from qr.replay.lee import LeeController

    lee = LeeController()
    lee.reset(crazyflie, 0.041)
    for described in (lee.describe(), PythonLee().describe()):
        record = ControllerRecord.of(described)
        assert record.to_dict() == described and hash(record)
    assert ControllerRecord.of(lee.describe()).gains[0] == ("mass", 0.041)
