"""The controller interface the replay flies: plug in your own.

A controller is a class with ``rate_hz`` and two methods::

    class MyController(qr.replay.controller.Controller):
        rate_hz = 500.0

        def reset(self, vehicle, mass):       # once per flight: the vehicle file flown, the mass to assume
            ...
        def __call__(self, t, state, setpoint) -> Command:
            return Command(thrust=..., torque=(tx, ty, tz))       # N along body z; N m, body
            # or Command(rotor_speeds=(u1, u2, u3, u4))           # in the vehicle's rotor_speed_unit

It is called every ``1 / rate_hz`` s with the time (s, the log's clock), the :class:`State` it sees and
the :class:`Setpoint` of that instant, and its command is held until the next call (zero-order hold).
A thrust-and-torque command goes through the replay's mixer (the firmware's power distribution, or the
vehicle's inverse rotor map); rotor speeds go to the motors directly.  Either way the vehicle's rotor
limits and first-order motor response follow.  ``qr replay --controller MODULE:CLASS`` flies such a
class (constructed without arguments); :mod:`qr.replay.lee` (the Crazyflie firmware's Lee controller)
and :mod:`qr.replay.rotorpy_controller` (RotorPy's ``SE3Control``) implement it.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field

import numpy as np

from ..errors import QrInputError


@dataclass(frozen=True)
class State:
    """What the controller sees: position ``p`` (m) and velocity ``v`` (m/s) of the tracked point in the
    world frame (z up), attitude ``q`` (body → world, scalar first), body rate ``w`` (rad/s, body)."""

    p: np.ndarray
    v: np.ndarray
    q: np.ndarray
    w: np.ndarray


@dataclass(frozen=True)
class Setpoint:
    """The reference at one instant (world frame, SI): position, velocity, acceleration, jerk, snap;
    yaw (rad), its rate and acceleration."""

    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    j: np.ndarray = field(default_factory=lambda: np.zeros(3))
    s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    yaw: float = 0.0
    yaw_rate: float = 0.0
    yaw_acc: float = 0.0


@dataclass(frozen=True)
class Command:
    """Collective ``thrust`` (N, along body z) and body ``torque`` (N m), or ``rotor_speeds`` (4, the
    vehicle's unit)."""

    thrust: float | None = None
    torque: tuple | np.ndarray | None = None
    rotor_speeds: tuple | np.ndarray | None = None

    def __post_init__(self):
        if (self.rotor_speeds is None) == (self.thrust is None or self.torque is None):
            raise ValueError("a Command holds thrust and torque, or rotor_speeds")


class Controller:
    """Base class of the replay's controllers (see the module's documentation)."""

    name = "controller"
    rate_hz = 500.0

    def reset(self, vehicle, mass: float) -> None:
        """Start of a flight: ``vehicle`` (:class:`qr.vehicle.Vehicle`, the file flown) and ``mass`` (kg,
        the mass the controller is told: its mass parameter)."""

    def __call__(self, t: float, state: State, setpoint: Setpoint) -> Command:
        raise NotImplementedError

    def describe(self) -> dict:
        """What ``replay.json`` records of it (name, rate, gains)."""
        return {"name": self.name, "rate_hz": float(self.rate_hz)}


def controller_named(name: str, settings: dict | None = None) -> Controller:
    """The controller ``--controller`` names: ``lee`` (gains ``settings``: the ``controller`` config group),
    ``rotorpy_se3``, or ``MODULE:CLASS``."""
    if name == "lee":
        from .lee import LeeController, LeeGains

        return LeeController(LeeGains.from_dict(settings or {}))
    if name == "rotorpy_se3":
        from .rotorpy_controller import RotorPySE3

        return RotorPySE3()
    if ":" in name:
        module, cls = name.split(":", 1)
        try:
            obj = getattr(importlib.import_module(module), cls)
        except (ImportError, AttributeError) as e:
            raise QrInputError(name, f"controller class cannot be imported ({e})",
                               "give --controller MODULE:CLASS of an importable class (on PYTHONPATH)") from None
        ctrl = obj()
        if not callable(ctrl) or not hasattr(ctrl, "reset"):
            raise QrInputError(name, "is not a controller (it needs reset(vehicle, mass) and __call__(t, state, "
                                     "setpoint) -> Command)", "subclass qr.replay.controller.Controller")
        return ctrl
    raise QrInputError(name, "unknown controller", "use --controller lee, rotorpy_se3 or MODULE:CLASS")


def controllers_for(name: str, settings: dict, given: set[str] = frozenset()):
    """``log -> Controller``: a fresh controller per flight.  A ``qr synth`` flight made under the Lee
    controller is replayed with the gains it was flown with (recorded in its ``truth.json``), the keys the
    user set (``given``: ``controller.KEY=...``) applied on top."""
    def make(log) -> Controller:
        recorded = ((log.synth or {}).get("setpoints") or {}).get("controller") if log is not None else None
        if name == "lee" and recorded and recorded.get("name") == "lee":
            gains = {**recorded.get("gains", {}), **{k: v for k, v in settings.items() if k in given}}
            return controller_named(name, gains)
        return controller_named(name, settings)
    return make
