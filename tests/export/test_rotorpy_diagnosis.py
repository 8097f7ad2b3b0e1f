"""The other direction: flights RotorPy simulates (its own Multirotor, controller and trajectories), written as
canonical logs, diagnosed by `qr diagnose`.

RotorPy's own Hummingbird (rotorpy/vehicles/hummingbird_params.py: rotor drag k_d, induced-inflow drag k_z,
translational lift k_h, parasitic drag c_D, motor lag tau_m = 5 ms) with a flapping coefficient RotorPy's
files leave at 0 (k_flap = -1e-5 N m s/m per rad/s: nose-up with forward speed, as the Crazyflie measured),
flown by its SE3Control along two of its 3-D circles, 30 s each at 100 Hz.  Through the export's mapping
read backwards (qr.sim.rotorpy_flights.expected_effects): rotor_drag k = k_d, blade_flapping
k = -k_flap Σω_hover, linear_drag kz = k_z Σω_hover.  Aerodynamics off, nothing may be named.

RotorPy's rotor drag acts at the hubs: its moment is rotor_drag_moment, named with rotor_drag's k (the
spec: one rotor drag); its translational lift k_h is translational_lift k.  What else a diagnosis names
there is RotorPy physics qr's catalog has no term for, named through the nearest catalog term
(docs/export.md, measured by benchmarks/rotorpy.py): the induced-inflow drag's moments at the hubs (a
roll/pitch-rate damping) as inertia_error, the parasitic drag (0.6 % of the weight at these 2.4 m/s)
inside the linear drag's kx, ky.  Whatever is named, nothing is said about the vehicle file: RotorPy's
coefficients are the file's.
"""

import pytest

pytest.importorskip("rotorpy")

from qr.sim.rotorpy_flights import expected_effects  # noqa: E402
from rotorpy_cases import diagnose_circles, hummingbird  # noqa: E402


def diagnose(qp, aero, tmp_path):
    doc = diagnose_circles(qp, tmp_path, aero=aero)
    return {e["name"]: e["parameters"] for e in doc["effects"]}, doc


def test_rotorpy_aerodynamics_are_named_through_the_mapping(tmp_path):
    qp = hummingbird()
    expected = expected_effects(qp)
    named, doc = diagnose(qp, True, tmp_path)
    for name, key in (("rotor_drag", "k"), ("rotor_drag_moment", "k"), ("translational_lift", "k"),
                      ("blade_flapping", "k"), ("linear_drag", "kz")):
        assert name in named, (name, named)
        assert named[name][key] == pytest.approx(expected[name][key], rel=0.2), (name, named[name], expected[name])
    assert named["rotor_drag"] == named["rotor_drag_moment"]  # one rotor drag
    assert not {"actuator_delay", "yaw_torque_gain", "thrust_gain", "mass_error"} & set(named)  # its motor lag acts
    # before the logged rotor speeds; its C_Q and C_T are the file's, its rotor drag's moment no C_Q error
    assert not doc["vehicle_file"], doc["vehicle_file"]


def test_nothing_is_named_on_a_rotorpy_flight_without_aerodynamics(tmp_path):
    assert diagnose(hummingbird(), False, tmp_path)[0] == {}
