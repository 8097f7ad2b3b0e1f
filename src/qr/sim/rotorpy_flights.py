"""Flights simulated by RotorPy (an independent simulator qr did not write), as canonical flight logs.

RotorPy's own ``Multirotor`` flown by its own ``SE3Control``, logged with qr's synthetic noise
(:func:`qr.sim.synth.add_noise`); for the diagnosis tests and ``benchmarks/rotorpy.py`` (the test extra
``rotorpy``).  The expected diagnosis reads the export's mapping backwards (``k_d``, ``k_h``, ``k_flap``,
``c_D``, ``k_z``): docs/export.md "RotorPy's flights, diagnosed by qr".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..flight import POSITION, QUATERNION, ROTORS

AERO_KEYS = ("k_d", "k_z", "k_h", "k_flap", "c_Dx", "c_Dy", "c_Dz")


def vehicle_dict(qp: dict, name: str) -> dict:
    """The nominal qr vehicle of RotorPy parameters (rotor speeds in rad/s; CG at the rotors' centre)."""
    pos = np.array([np.asarray(p, float) for p in qp["rotor_pos"].values()])
    if np.ptp(pos[:, 2]) != 0 or any(qp[k] != 0 for k in ("Ixy", "Ixz", "Iyz")):
        raise ValueError("qr's vehicle files take rotor hubs at one height and principal inertias on the body axes")
    hub = {"hub_z": float(pos[0, 2])} if pos[0, 2] else {}
    return {"name": name, **hub, "mass": float(qp["mass"]), "inertia": [float(qp[k]) for k in ("Ixx", "Iyy", "Izz")],
            "thrust_coeff": float(qp["k_eta"]), "torque_coeff": float(qp["k_m"]), "rotor_speed_unit": "rad_s",
            "layout": [{"x": float(x), "y": float(y), "yaw_sign": float(s)}
                       for (x, y, _), s in zip(pos, qp["rotor_directions"])],
            "rotor_speed_min": float(qp["rotor_speed_min"]), "rotor_speed_max": float(qp["rotor_speed_max"]),
            "motor_time_constant": float(qp["tau_m"])}


def hover_speed(qp: dict) -> float:
    return math.sqrt(qp["mass"] * 9.81 / (qp["num_rotors"] * qp["k_eta"]))


def expected_effects(qp: dict) -> dict[str, dict]:
    """The catalog effects (name -> parameters) a diagnosis should name on a flight of ``qp``'s aerodynamics."""
    omega_sum = qp["num_rotors"] * hover_speed(qp)
    out = {}
    if qp.get("k_d", 0):  # the H-force at the hubs: its force and its moment, one k
        out["rotor_drag"] = {"k": float(qp["k_d"])}
        out["rotor_drag_moment"] = {"k": float(qp["k_d"])}
    if qp.get("k_h", 0):
        out["translational_lift"] = {"k": float(qp["k_h"])}
    if qp.get("k_z", 0):
        out["linear_drag"] = {"kx": 0.0, "ky": 0.0, "kz": float(qp["k_z"]) * omega_sum}
    if qp.get("k_flap", 0):
        out["blade_flapping"] = {"k": -float(qp["k_flap"]) * omega_sum}
    if any(qp.get(k, 0) for k in ("c_Dx", "c_Dy", "c_Dz")):
        out["quadratic_drag"] = {"cx": float(qp["c_Dx"]), "cy": float(qp["c_Dy"]), "cz": float(qp["c_Dz"])}
    return out


@dataclass(frozen=True)
class Circle:
    """RotorPy's ThreeDCircularTraj: radius (m) and frequency (Hz) per axis, about a centre."""

    radius: tuple = (2.0, 2.0, 0.3)
    freq: tuple = (0.2, 0.2, 0.35)
    center: tuple = (0.0, 0.0, 1.5)

    def make(self):
        from rotorpy.trajectories.circular_traj import ThreeDCircularTraj

        return ThreeDCircularTraj(center=np.array(self.center), radius=np.array(self.radius),
                                  freq=np.array(self.freq))


@dataclass(frozen=True)
class RotorpyFlight:
    duration: float = 40.0  # s
    dt: float = 0.01  # s: RotorPy's control step and the log's sample period
    aero: bool = True
    seed: int = 0
    trajectory: Circle = field(default_factory=Circle)
    rtol: float = 1e-5  # RotorPy's integrator (RK45) per step: positions within 2e-7 m of rtol 1e-9's, far below the log's noise
    wind: tuple = (0.0, 0.0, 0.0)  # m/s, world: a steady wind (RotorPy keeps its state's wind; its aerodynamics act on the airspeed)
    rotor_gains: tuple = (1.0, 1.0, 1.0, 1.0)  # each rotor's thrust and drag torque over the file's (a weak rotor)


def fly(qp: dict, cfg: RotorpyFlight) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(flight, truth)``: a RotorPy flight of ``qp`` as a canonical log (noisy) and its true states."""
    from rotorpy.controllers.quadrotor_control import SE3Control
    from rotorpy.vehicles.multirotor import Multirotor

    from ..vehicle import vehicle_from_dict
    from .synth import NoiseConfig, add_noise

    traj = cfg.trajectory.make()
    flat = traj.update(0.0)
    w0 = np.full(qp["num_rotors"], hover_speed(qp))
    state = {"x": np.asarray(flat["x"], float), "v": np.asarray(flat["x_dot"], float),
             "q": np.array([0.0, 0.0, 0.0, 1.0]), "w": np.zeros(3), "wind": np.asarray(cfg.wind, float),
             "rotor_speeds": w0}
    kind = Multirotor if all(g == 1.0 for g in cfg.rotor_gains) else _with_rotor_gains(Multirotor, cfg.rotor_gains)
    vehicle = kind(qp, initial_state=state, aero=cfg.aero,
                   integrator_kwargs={"method": "RK45", "rtol": cfg.rtol, "atol": 1e-9})
    controller = SE3Control(qp)
    n = int(round(cfg.duration / cfg.dt))
    rows = np.empty((n + 1, 12))
    for k in range(n + 1):
        q = state["q"]
        rows[k] = [k * cfg.dt, *state["x"], q[3], q[0], q[1], q[2], *state["rotor_speeds"]]
        if k == n:
            break
        control = controller.update(k * cfg.dt, state, traj.update(k * cfg.dt))
        state = vehicle.step(state, control, cfg.dt)
    truth = pd.DataFrame(rows, columns=["t", *POSITION, *QUATERNION, *ROTORS])
    qr_vehicle = vehicle_from_dict(vehicle_dict(qp, "rotorpy"))
    flight = add_noise(truth, qr_vehicle, NoiseConfig(), np.random.default_rng([cfg.seed, 27]))
    return flight, truth


def _with_rotor_gains(multirotor: type, gains: tuple) -> type:
    """RotorPy's ``Multirotor`` whose rotor i makes ``gains[i]`` of its thrust ``k_eta ω²`` and of its drag
    torque ``k_m ω²`` (a weak or damaged rotor: the propeller's torque scales with its thrust); RotorPy has
    one ``k_eta`` for all rotors."""
    extra_share = np.asarray(gains, float) - 1.0

    class WithRotorGains(multirotor):
        def compute_body_wrench(self, body_rates, rotor_speeds, body_airspeed_vector):
            force, moment = super().compute_body_wrench(body_rates, rotor_speeds, body_airspeed_vector)
            extra = extra_share * self.k_eta * rotor_speeds**2
            moment = moment + np.cross(self.rotor_geometry, np.outer(extra, [0.0, 0.0, 1.0])).sum(axis=0)
            moment[2] += np.sum(extra_share * self.rotor_dir * self.k_m * rotor_speeds**2)
            return force + np.array([0.0, 0.0, extra.sum()]), moment

    return WithRotorGains
