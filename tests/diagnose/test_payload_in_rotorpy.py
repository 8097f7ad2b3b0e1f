"""A payload is a mass error, not a C_T error plus an inertia error (qr.diagnose.fit, the slow balance's swap).

RotorPy's Hummingbird (500 g) carries 50 g more than its vehicle file says, its inertia and rotors unchanged,
along two of its circles (30 s each, aerodynamics off).  In force a C_T error and a mass error are one term
(gain = m / (m + dm) = 0.909); a C_T error also scales the roll/pitch torque.  The selection could not tell
them apart and named the simpler, thrust_gain; its torque scaled by 0.909 then left a summed pitch residual
that the slow torque balance named as Jyy x 0.9 (dJyy = -3.8e-4 +- 8.5e-5 kg m^2): an inertia error RotorPy's
vehicle does not have.  With mass_error instead the balance names nothing, so mass_error is named, with
thrust_gain in confounded_with, and no inertia error.
"""

import pytest

pytest.importorskip("rotorpy")

from rotorpy_cases import diagnose_circles, hummingbird  # noqa: E402

PAYLOAD = 0.05  # kg


def test_a_payload_in_rotorpy_is_a_mass_error_without_an_inertia_error(tmp_path):
    filed = hummingbird(k_flap=0.0)
    doc = diagnose_circles(hummingbird(k_flap=0.0, mass=filed["mass"] + PAYLOAD), tmp_path, filed, aero=False)
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
