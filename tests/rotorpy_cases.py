"""RotorPy's Hummingbird flown along two of its 3-D circles (30 s each at 100 Hz, qr's synthetic noise) and
diagnosed by ``qr diagnose``'s library entry: the independent-simulator cases of the diagnosis tests."""

from __future__ import annotations

import copy
from pathlib import Path

from qr.flight import write_flight
from qr.sim.rotorpy_flights import Circle, RotorpyFlight, fly, vehicle_dict
from qr.stages.diagnose import run_diagnosis
from qr.vehicle import save_vehicle, vehicle_from_dict

CIRCLES = [Circle(), Circle(radius=(1.5, 2.5, 0.4), freq=(0.25, 0.15, 0.3))]
K_FLAP = -1e-5  # RotorPy's files leave flapping at 0: nose-up with forward speed, as the Crazyflie measured


def hummingbird(k_flap: float = K_FLAP, **changes) -> dict:
    """RotorPy's own Hummingbird parameters, with ``k_flap`` and ``changes``."""
    from rotorpy.vehicles.hummingbird_params import quad_params

    qp = copy.deepcopy(quad_params)
    qp["k_flap"] = k_flap
    qp.update(changes)
    return qp


def diagnose_circles(flown: dict, folder: Path, filed: dict | None = None, **flight) -> dict:
    """``diagnosis.json`` of the two circles flown by ``flown`` (``flight``: :class:`RotorpyFlight` fields),
    diagnosed against the vehicle file of ``filed`` (default: ``flown``'s own)."""
    flights = []
    for seed, circle in enumerate(CIRCLES):
        log, _ = fly(flown, RotorpyFlight(duration=30.0, seed=seed, trajectory=circle, **flight))
        flights.append(folder / f"rotorpy{seed}.csv")
        write_flight(log, flights[-1])
    save_vehicle(vehicle_from_dict(vehicle_dict(filed or flown, "hummingbird-rotorpy")), folder / "vehicle.yaml")
    return run_diagnosis(flights, folder / "vehicle.yaml", folder / "diag", [], log=lambda m: None, figures=False)
