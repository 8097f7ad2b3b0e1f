"""One replay: :func:`run` flies every vehicle file along every flight's rebuilt setpoints and returns a
:class:`Replay`, by named steps per flight:

1. ``setup``: the setpoints (trajectory, time scale, start time and point: given, recorded by ``qr synth``,
   or found from the flight, :mod:`.alignment`), the controller's mass parameter, the actuation (mixer and
   motor map, :mod:`.mixer`), the window and the initial state;
2. ``fly``: each vehicle in closed loop (:func:`qr.replay.fly.fly`);
3. ``compare``: against the logged flight at its pose stamps (:mod:`.compare`).

``replay.json`` is :func:`qr.replay.document.document` of it, ``report.md`` and the figures
:mod:`qr.replay.report`'s; the stage (:mod:`qr.stages.replay`) reads, runs, writes and tracks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import QrInputError
from ..flight import POSITION, QUATERNION, ROTORS
from .alignment import Alignment, from_position, from_thrust
from .compare import Errors, Track, compare, pool
from .controller import Controller, ControllerRecord
from .fly import Actuation, fly, initial_state
from .logs import COMMANDS, ReplayLog
from .mixer import MotorMap, fit_motor_map
from .settings import ReplaySettings
from .setpoints import PiecewisePolynomial, Setpoints, read_pieces

MIN_WINDOW_S = 0.5


@dataclass(frozen=True)
class Setup:
    """What the replay rebuilt of one flight."""

    setpoints: Setpoints
    alignment: Alignment
    trajectory: str
    mixer: str  # "crazyflie" | "ideal"
    actuation: Actuation
    controller_mass: float
    mass_source: str
    window: tuple[float, float]  # (t0, t1) s, log clock
    initial: tuple[np.ndarray, ...]  # tracked-point p, v, q, w, u at t0
    thrust_kind: str  # "command" | "rotor"
    sim_rate_hz: float  # the integration rate (a qr synth flight's own)


@dataclass(frozen=True)
class ModelFlight:
    """One vehicle flown along one flight, sampled at the flight's pose stamps (NaN after it was lost)."""

    label: str
    vehicle: str
    errors: Errors
    p: np.ndarray
    q: np.ndarray
    u: np.ndarray
    thrust: np.ndarray


@dataclass(frozen=True)
class FlightReplay:
    name: str
    path: str
    setup: Setup
    t: np.ndarray  # the pose stamps inside the window
    logged: Track  # at t
    models: tuple[ModelFlight, ...]  # one per vehicle


@dataclass(frozen=True)
class Replay:
    flights: tuple[FlightReplay, ...]
    vehicles: tuple[str, ...]  # paths (or names) as given
    labels: tuple[str, ...]
    controller: ControllerRecord  # the controller as it describes itself (name, rate, gains)
    settings: ReplaySettings
    rotor_unit: str
    pooled: tuple[Errors, ...]  # per vehicle (in labels' order): its errors over all flights
    unknown: tuple[str, ...] = ()  # what the replay does not model, one sentence each


def run(logs: list[ReplayLog], vehicles: list, vehicle_files: list[str], labels: list[str], controllers,
        settings: ReplaySettings, say=lambda msg: None) -> Replay:
    """Replay ``logs`` with each of ``vehicles`` (labelled ``labels``); ``controllers(log) -> Controller``
    gives the controller to fly on a flight (a fresh one; its gains may depend on the flight)."""
    flights = []
    for i, log in enumerate(logs):
        controller = controllers(log)
        setup = prepare(log, vehicles[0], controller, settings.for_flight(i, len(logs)), say)
        say(f"{log.name}: {setup.alignment.source} setpoints, start {setup.alignment.offset_s:.3f} s, "
            f"controller mass {setup.controller_mass:.4g} kg, {setup.mixer} mixer")
        flights.append(fly_all(log, setup, vehicles, vehicle_files, labels, controller, settings, say))
    pooled = tuple(pool([f.models[i].errors for f in flights]) for i in range(len(labels)))
    return Replay(tuple(flights), tuple(vehicle_files), tuple(labels), ControllerRecord.of(controller.describe()), settings,
                  vehicles[0].rotor_speed_unit, pooled, tuple(unknowns(flights, vehicles, settings)))


def prepare(log: ReplayLog, vehicle, controller: Controller, settings: ReplaySettings, say) -> Setup:
    """Step 1: setpoints, controller mass, actuation, window and initial state of one flight."""
    t, p, v, R, q, w = log.controller_view()
    lee = getattr(controller, "name", "") == "lee"
    given_mass = getattr(getattr(controller, "gains", None), "mass", None)
    if log.synth is not None:
        sp_doc = log.synth["setpoints"]
        traj = PiecewisePolynomial(np.asarray(sp_doc["durations"], float), np.asarray(sp_doc["coeffs"], float),
                                   sp_doc.get("name", "trajectory"))
        al = Alignment(float(sp_doc["offset_s"]), 0.0, tuple(sp_doc["origin"]), float(sp_doc["controller_mass"]),
                       "synth")
        sp = Setpoints(traj, float(sp_doc["timescale"]), al.offset_s, al.origin, float(sp_doc.get("yaw0", 0.0)))
        trajectory = f"{traj.name} (recorded by qr synth)"
    else:
        if settings.trajectory is None:
            raise QrInputError(log.path, "the flight carries no setpoints and no trajectory is given",
                               "add replay.trajectory=PATH of the trajectory it flew (a crazyswarm CSV, e.g. "
                               "figure8.csv) and replay.timescale=S")
        traj = read_pieces(settings.trajectory)
        trajectory = str(settings.trajectory)
        al = _align(log, traj, settings, controller, lee, given_mass, t, p, v, R)
        sp = Setpoints(traj, settings.timescale, al.offset_s, al.origin, settings.yaw0)
    mass, mass_source = _mass(given_mass, al, vehicle)
    mixer = settings.mixer if settings.mixer != "auto" else ("crazyflie" if log.has_commands else "ideal")
    if log.synth is not None and settings.mixer == "auto":
        mixer = log.synth["setpoints"].get("mixer", "ideal")
    actuation = _actuation(log, vehicle, mixer, settings)
    t0, t1 = _window(log, sp, settings)
    tl = log.pose["t"].to_numpy(float)
    if log.truth is not None:  # a qr synth folder: its true initial state
        tr = log.truth
        i = int(np.argmin(np.abs(tr["t"].to_numpy() - t0)))
        initial = (tr[POSITION].to_numpy()[i], tr[["vx", "vy", "vz"]].to_numpy()[i], tr[QUATERNION].to_numpy()[i],
                   tr[["wx", "wy", "wz"]].to_numpy()[i], tr[ROTORS].to_numpy()[i])
    else:
        initial = (_at(t, p, t0), _at(t, v, t0), _at(t, q, t0), _at(t, w, t0), _at(tl, log.pose[ROTORS].to_numpy(float), t0))
    kind = "command" if mixer == "crazyflie" and log.has_commands else "rotor"
    rate = float(log.synth["setpoints"].get("sim_rate_hz", settings.sim_rate_hz)) if log.synth else settings.sim_rate_hz
    return Setup(sp, al, trajectory, mixer, actuation, mass, mass_source, (t0, t1), initial, kind, rate)


def _align(log, traj, settings, controller, lee, given_mass, t, p, v, R) -> Alignment:
    if settings.offset_s is not None and (settings.origin is not None or not log.has_commands):
        origin = settings.origin
        if origin is None:  # the start point alone from the position, at the given start time
            r = Setpoints(traj, settings.timescale, settings.offset_s).at(t, order=0)["p"]
            origin = tuple(float(x) for x in np.nanmean(p - r, axis=0))
        return Alignment(settings.offset_s, None, tuple(origin), given_mass, "given")
    if log.has_commands and lee:
        mixer = settings.firmware
        thrust = mixer.thrust_of(log.fast[COMMANDS].to_numpy(float), log.vbat())
        tf = log.fast["t"].to_numpy(float)
        al = from_thrust(t, p, v, R, np.interp(t, tf, thrust), traj, settings.timescale, controller.gains,
                         given_mass, settings.origin, log.path)
    else:
        al = from_position(t, p, traj, settings.timescale, settings.origin, log.path)
    if settings.offset_s is not None:
        al = Alignment(settings.offset_s, None, al.origin, al.mass, al.source + " (start time given)")
    if al.mass is not None and not (0 < al.mass < 1e4):
        raise QrInputError(log.path, f"the controller's mass found from the motor commands is {al.mass:.4g} kg",
                           "check replay.trajectory and replay.timescale (the flight's), or give controller.mass")
    return al


def _mass(given, al: Alignment, vehicle) -> tuple[float, str]:
    if al.source == "synth":
        same = given is None or given == al.mass
        return float(al.mass if same else given), "recorded by qr synth" if same else "given (controller.mass)"
    if given is not None:
        return float(given), "given (controller.mass)"
    if al.mass is not None:
        return float(al.mass), {"commands": "found from the motor commands", "synth": "recorded by qr synth"}.get(
            al.source, al.source)
    return float(vehicle.mass), "the first vehicle file's mass"


def _actuation(log: ReplayLog, vehicle, mixer: str, settings: ReplaySettings) -> Actuation:
    if mixer == "ideal":
        return Actuation()
    cf = settings.firmware
    vbat = log.vbat()
    kind = settings.motor_map
    if kind == "auto":
        kind = "fit" if log.has_commands and all(c in log.fast for c in ROTORS) else "firmware"
    if kind == "fit":
        if not (log.has_commands and all(c in log.fast for c in ROTORS)):
            raise QrInputError(log.path, "replay.motor_map=fit needs the logged motor commands and rotor speeds",
                               "use replay.motor_map=firmware")
        f = log.fast
        return Actuation(cf, fit_motor_map(f["t"].to_numpy(float), f[COMMANDS].to_numpy(float),
                                           f[ROTORS].to_numpy(float), vehicle.motor_time_constant), vbat)
    return Actuation(cf, MotorMap("firmware"), vbat)


def _window(log: ReplayLog, sp: Setpoints, settings: ReplaySettings) -> tuple[float, float]:
    tl = log.pose["t"].to_numpy(float)
    ok = np.isfinite(log.pose[POSITION].to_numpy(float)).all(axis=1)
    start = tl[ok][0]
    if log.fast is not None:
        start = max(start, float(log.fast["t"].iloc[0]))
    end = min(float(tl[ok][-1]), sp.end_s + settings.hold_s)
    if end - start < MIN_WINDOW_S or sp.end_s < start or sp.offset_s > end:
        raise QrInputError(log.path, f"the log ({start:.2f}–{tl[-1]:.2f} s) does not overlap the trajectory "
                                     f"({sp.offset_s:.2f}–{sp.end_s:.2f} s) for {MIN_WINDOW_S} s",
                           "check replay.trajectory, replay.timescale and replay.offset_s")
    return float(start), float(end)


def _at(t, y, t0):
    y = np.asarray(y, float)
    return np.array([np.interp(t0, t[np.isfinite(y[:, i])], y[np.isfinite(y[:, i]), i]) for i in range(y.shape[1])])


def fly_all(log: ReplayLog, setup: Setup, vehicles, vehicle_files, labels, controller, settings, say) -> FlightReplay:
    """Steps 2 and 3: each vehicle flown and compared."""
    t0, t1 = setup.window
    tl = log.pose["t"].to_numpy(float)
    inside = (tl >= t0 - 1e-9) & (tl <= t1 + 1e-9)
    t = tl[inside]
    u = log.pose[ROTORS].to_numpy(float)[inside]
    logged = Track(log.pose[POSITION].to_numpy(float)[inside], log.pose[QUATERNION].to_numpy(float)[inside], u,
                   _logged_thrust(log, setup, t, u, vehicles[0]))
    pos = (tl, log.pose[POSITION].to_numpy(float))
    models = []
    for veh, path, label in zip(vehicles, vehicle_files, labels):
        x0 = initial_state(veh, *setup.initial)
        say(f"{log.name}: flying {label}")
        flown = fly(veh, controller, setup.setpoints, x0, t0, t1, setup.controller_mass, setup.actuation,
                    setup.sim_rate_hz, pos, settings.max_error_m, 0.0 if log.synth else settings.settle_s)
        sim = _sampled(flown, t, setup, vehicles[0])
        err = compare(t, t0, logged, sim, settings.part_position_m, settings.part_attitude_deg, flown.diverged_at_s)
        models.append(ModelFlight(label, str(path), err, *sim))
    return FlightReplay(log.name, log.path, setup, t, logged, tuple(models))


def _logged_thrust(log, setup: Setup, t, u, first_vehicle) -> np.ndarray:
    if setup.thrust_kind == "command":
        thrust = setup.actuation.mixer.thrust_of(log.fast[COMMANDS].to_numpy(float), log.vbat())
        return np.interp(t, log.fast["t"].to_numpy(float), thrust)
    return first_vehicle.thrust_coeff * np.sum(u ** 2, axis=1)


def _sampled(flown, t, setup: Setup, first_vehicle) -> Track:
    """The simulation at the stamps ``t`` (linear between its steps; NaN after it ended)."""
    end = flown.t[-1] if len(flown.t) else -np.inf
    keep = t <= end + 1e-12

    def interp(y):
        out = np.full((len(t), y.shape[1]), np.nan)
        for i in range(y.shape[1]):
            out[keep, i] = np.interp(t[keep], flown.t, y[:, i])
        return out

    q = interp(flown.q)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    u = interp(flown.u)
    if setup.thrust_kind == "command":
        thrust = interp(setup.actuation.mixer.thrust_of(flown.duties, setup.actuation.vbat)[:, None])[:, 0]
    else:
        thrust = first_vehicle.thrust_coeff * np.sum(u ** 2, axis=1)
    return Track(interp(flown.p), q, u, thrust)


def unknowns(flights, vehicles, settings: ReplaySettings) -> list[str]:
    """What the replay does not model, each said once, generated from what it used."""
    out = ["the on-board state estimator and sensor noise: the simulated controller sees the true state",
           "disturbances the log shows (wind, a cable's pull, ground effect the vehicle file lacks): only what "
           "each vehicle file holds acts"]
    setups = [f.setup for f in flights]
    fits = [s.actuation.motor_map for s in setups if s.actuation.motor_map is not None and s.actuation.motor_map.kind == "fit"]
    if fits:
        out.append("the motor map from PWM to rotor speed: fitted per rotor on each flight (u = a + b pwm through a "
                   f"first-order lag of the vehicle's time constant; RMS {max(m.rms for m in fits):.3g} "
                   f"{vehicles[0].rotor_speed_unit} at worst); how a motor departs from it (battery sag, "
                   "its own dynamics) is not modelled")
    if any(s.actuation.motor_map is not None and s.actuation.motor_map.kind == "firmware" for s in setups):
        out.append("the motor map from PWM to rotor speed: assumed to be the firmware's own model (the rotor "
                   "speed at which the vehicle's C_T gives the force the firmware asked for); not measured")
    if any(s.mixer == "ideal" for s in setups):
        out.append("the vehicle's own mixer and motor saturation: rotor speeds from the vehicle's inverse rotor map, "
                   "clipped to its rotor limits")
    if any(s.alignment.source == "position" for s in setups):
        out.append("the setpoints' start time and point: found from the logged position (no motor commands), so "
                   "the vehicle's tracking lag and steady error are partly taken for the setpoint's")
    if any(s.mass_source == "the first vehicle file's mass" for s in setups):
        out.append("the controller's mass parameter: not logged; the first vehicle file's mass is assumed")
    if any(not v.raw.get("rotor_speed_max") for v in vehicles):
        out.append("the rotor-speed limit of a vehicle file without rotor_speed_max: √2.5 × its hover speed assumed "
                   "(qr's default)")
    return out
