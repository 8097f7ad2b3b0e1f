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

from dataclasses import dataclass, field

import numpy as np



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


Gain = float | tuple[float, ...] | None


@dataclass(frozen=True)
class ControllerRecord:
    """The controller flown as it describes itself (:meth:`Controller.describe`): replay.json's ``controller``."""

    name: str
    rate_hz: float
    gains: tuple[tuple[str, Gain], ...] | None = None  # (name, number or numbers) in its order; None: none given

    @classmethod
    def of(cls, description: dict) -> ControllerRecord:
        """The record of a description (its ``name``, ``rate_hz`` and ``gains``: the keys replay.json records)."""
        gains = description.get("gains")
        return cls(description["name"], description["rate_hz"], None if gains is None else
                   tuple((k, tuple(v) if isinstance(v, list) else v) for k, v in gains.items()))

    def to_dict(self) -> dict:
        d = {"name": self.name, "rate_hz": self.rate_hz}
        if self.gains is not None:
            d["gains"] = {k: list(v) if isinstance(v, tuple) else v for k, v in self.gains}
        return d


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
        """What ``replay.json`` records of it: ``name``, ``rate_hz`` and, if it has them, ``gains`` (each a number
        or a list of numbers; :class:`ControllerRecord`)."""
        return {"name": self.name, "rate_hz": float(self.rate_hz)}
