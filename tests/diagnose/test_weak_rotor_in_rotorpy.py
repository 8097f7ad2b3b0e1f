"""A weak rotor is one motor_imbalance, its drag torque with its thrust (qr.effects, qr.sim.plant).

RotorPy's Hummingbird whose rotor 2 makes 7 % less thrust and 7 % less drag torque at the same speed (a
damaged propeller: its torque scales with its thrust; qr.sim.rotorpy_flights.RotorpyFlight.rotor_gains), along
two of its circles (30 s each, aerodynamics off), diagnosed against the file of four equal rotors.  When
motor_imbalance scaled the thrust only, the rotors' yaw-sign pattern d1 + d3 - d2 - d4 changed neither the
force nor the roll/pitch torque at near-equal speeds, and the 7 % drag-torque deficit of rotor 2 was named
apart as a constant torque_bias tz = 0.0024 N m: d = (0.013, -0.086, 0.019, -0.015), s.e. 0.01, plus the bias.
With the drag torque in the term, the yaw torque fixes that pattern: rotor 2 alone, and nothing else named.
"""

import pytest

pytest.importorskip("rotorpy")

from rotorpy_cases import diagnose_circles, hummingbird  # noqa: E402

WEAK = 0.93  # rotor 2's thrust and drag torque over the file's


def test_a_weak_rotor_in_rotorpy_is_one_motor_imbalance(tmp_path):
    qp = hummingbird(k_flap=0.0)
    doc = diagnose_circles(qp, tmp_path, aero=False, rotor_gains=(1.0, WEAK, 1.0, 1.0))
    named = {e["name"]: e for e in doc["effects"]}
    assert set(named) == {"motor_imbalance"}, list(named)
    m = named["motor_imbalance"]
    for i, truth in enumerate((0.0, WEAK - 1.0, 0.0, 0.0), 1):
        est, se = m["parameters"][f"d{i}"], m["stderr"][f"d{i}"]
        assert abs(est - truth) <= max(4 * se, 0.003), (i, est, se)  # 0.003: a tenth of a 3 % imbalance
    assert doc["vehicle_file"] == []
