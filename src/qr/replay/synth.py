"""Synthetic flights under the Lee controller (``qr synth --controller lee``): the TRUE plant (the nominal
vehicle with the hidden effects) flown by :func:`qr.replay.fly.fly` along a crazyswarm trajectory, from a
hover at its start point.  What the replay needs to rebuild the flight is recorded (``truth.json``'s
``setpoints``): the trajectory's pieces, time scale, start time and point, the controller's gains and mass
(the NOMINAL vehicle's: what its pilot would set), the mixer and the integration rate.  Replayed with its
true vehicle, such a flight comes back to the last bit: the same function flies both."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..errors import QrInputError
from ..plant_state import P_MARKER, X_ROTORS
from ..sim.plant import true_params
from .fly import Actuation, accelerations, fly, initial_state
from .lee import LeeController, LeeGains
from .setpoints import Setpoints, read_pieces

START_S = 0.5  # s of hover at the start point before the trajectory starts
HOLD_S = 2.0  # s after its end (as the crazyswarm programs wait)


def setpoints_record(trajectory, timescale: float, origin, vehicle) -> dict:
    """The setpoints block of ``truth.json`` (without the integration rate)."""
    traj = read_pieces(trajectory)
    gains = LeeGains.firmware().scaled_to(vehicle.inertia, vehicle.mass)
    return {"name": traj.name, "durations": traj.durations.tolist(), "coeffs": traj.coeffs.tolist(),
            "timescale": float(timescale), "offset_s": START_S, "origin": [float(x) for x in origin], "yaw0": 0.0,
            "controller": {"name": "lee", "gains": gains.to_dict()}, "controller_mass": float(vehicle.mass),
            "mixer": "ideal"}


def duration_of(record: dict) -> float:
    return START_S + record["timescale"] * float(np.sum(record["durations"])) + HOLD_S


def lee_truth(vehicle, effects: list[dict], record: dict, duration: float, rate: float, sim_rate: float,
              columns: list[str]) -> pd.DataFrame:
    """Noise-free true states at the log stamps (``columns``: qr.sim.synth's truth columns)."""
    from ..sim.plant import tracked_point
    from .setpoints import PiecewisePolynomial

    true = vehicle.with_changes(effects=list(vehicle.effects) + list(effects))
    traj = PiecewisePolynomial(np.asarray(record["durations"]), np.asarray(record["coeffs"]), record["name"])
    sp = Setpoints(traj, record["timescale"], record["offset_s"], tuple(record["origin"]), record["yaw0"])
    ctrl = LeeController(LeeGains.from_dict(record["controller"]["gains"]))
    x0 = initial_state(true, np.asarray(record["origin"], float), np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]),
                       np.zeros(3), np.full(4, vehicle.hover_speed))
    flown = fly(true, ctrl, sp, x0, 0.0, duration, record["controller_mass"], Actuation(), sim_rate)
    if flown.diverged_at_s is not None:
        raise QrInputError("synthetic flight", f"the Lee controller lost the vehicle at t = {flown.diverged_at_s:.2f} s",
                           "lower the effects' sizes or slow the trajectory (--timescale above 1)")
    every = int(round(sim_rate / rate))
    k = np.arange(0, len(flown.t), every)
    a, alpha = accelerations(flown, true)
    P = true_params(true, list(true.effects))
    r = P[P_MARKER].copy()
    rows = []
    tau = true.motor_time_constant
    ref = sp.at(flown.t[k], order=0)["p"]
    for j, i in enumerate(k):
        p, v, acc = tracked_point(flown.x[i], a[i], alpha[i], r)
        rows.append([flown.t[i], *p, *v, *acc, *flown.q[i], *flown.w[i], *alpha[i], *flown.u[i],
                     *((flown.u_cmd[i] - flown.x[i, X_ROTORS]) / tau), *ref[j]])
    truth = pd.DataFrame(rows, columns=columns)
    if not np.all(np.isfinite(truth.to_numpy())):
        raise QrInputError("synthetic flight", "the closed loop diverged", "lower the effects' sizes")
    return truth
