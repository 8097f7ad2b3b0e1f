"""RotorPy's ``SE3Control`` (Lee, Leok & McClamroch's geometric controller as RotorPy ships it) flown by qr's
replay through :class:`qr.replay.controller.Controller` (``qr replay --controller rotorpy_se3``): an example
of plugging in a controller written for another simulator.

The adapter converts qr's state (scalar-first quaternion) and setpoint to RotorPy's dicts (scalar-last
quaternion, ``flat_output`` keys) and returns RotorPy's collective thrust and moment, which the replay's mixer
turns into rotor speeds; RotorPy's controller is built from the vehicle file through ``qr export``'s
mapping (:func:`qr.export.rotorpy.quad_params`), its mass the controller's mass parameter.  Flown along the
same setpoints, qr's replay and RotorPy's own ``Multirotor`` under this controller agree
(tests/replay/test_controller_interface.py)."""

from __future__ import annotations

import numpy as np

from ..errors import QrInputError
from .controller import Command, Controller


class RotorPySE3(Controller):
    name = "rotorpy_se3"
    rate_hz = 500.0

    def __init__(self, rate_hz: float = 500.0):
        self.rate_hz = rate_hz
        self._ctrl = None

    def reset(self, vehicle, mass: float) -> None:
        try:
            from rotorpy.controllers.quadrotor_control import SE3Control
        except ImportError:
            raise QrInputError("rotorpy_se3", "RotorPy is not installed", "pip install rotorpy, or use --controller "
                                                                           "lee") from None
        from ..export import mapping
        from ..export.rotorpy import quad_params

        params = quad_params(mapping.plant_of(vehicle))
        params["mass"] = float(mass)
        params["rotor_pos"] = {k: np.asarray(v, float) for k, v in params["rotor_pos"].items()}
        params["rotor_directions"] = np.asarray(params["rotor_directions"], float)
        params["rI"] = np.asarray(params["rI"], float)
        self._ctrl = SE3Control(params)

    def __call__(self, t, state, setpoint) -> Command:
        q = np.asarray(state.q, float)
        out = self._ctrl.update(t, {"x": np.asarray(state.p, float), "v": np.asarray(state.v, float),
                                    "q": np.array([q[1], q[2], q[3], q[0]]), "w": np.asarray(state.w, float)},
                                {"x": setpoint.p, "x_dot": setpoint.v, "x_ddot": setpoint.a, "x_dddot": setpoint.j,
                                 "x_ddddot": setpoint.s, "yaw": setpoint.yaw, "yaw_dot": setpoint.yaw_rate,
                                 "yaw_ddot": setpoint.yaw_acc})
        return Command(thrust=float(out["cmd_thrust"]), torque=np.asarray(out["cmd_moment"], float))

    def describe(self) -> dict:
        c = self._ctrl
        gains = {} if c is None else {"kp_pos": c.kp_pos.tolist(), "kd_pos": c.kd_pos.tolist(),
                                      "kp_att": float(c.kp_att), "kd_att": float(c.kd_att)}
        return {"name": self.name, "rate_hz": float(self.rate_hz), "gains": gains}
