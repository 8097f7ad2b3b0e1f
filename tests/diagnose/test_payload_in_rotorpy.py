"""A payload is a mass error, not a C_T error plus an inertia error (qr.diagnose.fit, the slow balance's swap).

RotorPy's Hummingbird (500 g) carries 50 g more than its vehicle file says, its inertia and rotors unchanged,
along two of its circles (30 s each, aerodynamics off).  In force a C_T error and a mass error are one term
(gain = m / (m + dm) = 0.909); a C_T error also scales the roll/pitch torque.  The selection could not tell
them apart and named the simpler, thrust_gain; its torque scaled by 0.909 then left a summed pitch residual
that the slow torque balance named as Jyy x 0.9 (dJyy = -3.8e-4 +- 8.5e-5 kg m^2): an inertia error RotorPy's
vehicle does not have.  With mass_error instead the balance names nothing, so mass_error is named, with
thrust_gain in confounded_with, and no inertia error.
"""

import copy

import pytest

pytest.importorskip("rotorpy")

from qr.flight import write_flight  # noqa: E402
from qr.sim.rotorpy_flights import Circle, RotorpyFlight, fly, vehicle_dict  # noqa: E402
from qr.stages.diagnose import run_diagnosis  # noqa: E402
from qr.vehicle import save_vehicle, vehicle_from_dict  # noqa: E402

PAYLOAD = 0.05  # kg


def test_a_payload_in_rotorpy_is_a_mass_error_without_an_inertia_error(tmp_path):
    from rotorpy.vehicles.hummingbird_params import quad_params

    flown = copy.deepcopy(quad_params)
    flown["mass"] = quad_params["mass"] + PAYLOAD
    flights = []
    for seed, circle in enumerate([Circle(), Circle(radius=(1.5, 2.5, 0.4), freq=(0.25, 0.15, 0.3))]):
        flight, _ = fly(flown, RotorpyFlight(duration=30.0, aero=False, seed=seed, trajectory=circle))
        flights.append(tmp_path / f"rotorpy{seed}.csv")
        write_flight(flight, flights[-1])
    save_vehicle(vehicle_from_dict(vehicle_dict(quad_params, "hummingbird-rotorpy")), tmp_path / "vehicle.yaml")
    doc = run_diagnosis(flights, tmp_path / "vehicle.yaml", tmp_path / "diag", [], log=lambda m: None, figures=False)
    named = {e["name"]: e for e in doc["effects"]}
    assert set(named) == {"mass_error"}, list(named)
    m = named["mass_error"]
    assert "thrust_gain" in m["confounded_with"]
    err = abs(m["parameters"]["dm"] - PAYLOAD)
    assert err <= max(4 * m["stderr"]["dm"], 0.05 * PAYLOAD), m
    slow = doc["selection"]["slow_torque"]
    assert not slow["named"] and "mass_error is named instead" in slow["note"], slow
    assert "with thrust_gain the balance named dJyy" in slow["note"]
    assert "mass_error is named instead" in (tmp_path / "diag" / "report.md").read_text()
    assert doc["vehicle_file"] == []
