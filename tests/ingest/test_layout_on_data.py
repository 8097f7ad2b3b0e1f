"""The Crazyflie rotor layout (signs and numbering) checked against the measured flights.

On these logs the roll/pitch rotor-map torque is dominated by rotor-speed
noise and steady trims, so τ_a ≈ -Γ for any layout and a residual-versus-speed
check cannot tell layouts apart.  What does: the measured angular acceleration
(500 Hz gyro) must move WITH the layout's torque on every axis, and no other
numbering of the four rotors may explain it better.  The convention check qr runs on every log
(``qr.conventions.check_rotor_layout``: every numbering of the file's rotors and of the plus and x layouts)
passes every shipped vehicle's measured flights, and says the file's layout fits.
"""

import itertools

import numpy as np
import pytest
from scipy.signal import savgol_filter

from conftest import DATA, VEHICLES
from qr.ingest.cf_usd import decode


def _gyro_alpha_and_speeds(n_flights=10):
    A, U = [], []
    for p in sorted((DATA / "brushless_flights" / "data").glob("eckart[0-9]*"))[:n_flights]:
        fast = decode(p)["fixedFrequency"]
        t = fast["timestamp_us"].to_numpy() * 1e-6
        dt = np.median(np.diff(t))
        gyro = np.radians(fast[["gyro.x", "gyro.y", "gyro.z"]].to_numpy())
        u2 = fast[["rpm.m1", "rpm.m2", "rpm.m3", "rpm.m4"]].to_numpy() ** 2
        alpha = savgol_filter(gyro, 11, 2, deriv=1, delta=dt, axis=0)
        # rotor speed leads the measured rate by ~2 samples (motor + gyro filtering)
        u2 = np.roll(savgol_filter(u2, 11, 2, axis=0), 2, axis=0)
        A.append(alpha[50:-50])
        U.append(u2[50:-50])
    return np.vstack(A), np.vstack(U)


def test_documented_layout_drives_the_measured_angular_acceleration(crazyflie):
    alpha, u2 = _gyro_alpha_and_speeds()
    J_alpha = alpha * crazyflie.inertia
    torque_rows = crazyflie.rotors.matrix[1:]

    def correlations(order):
        G = u2[:, order] @ torque_rows.T
        return np.array([np.corrcoef(J_alpha[:, k], G[:, k])[0, 1] for k in range(3)])

    documented = correlations([0, 1, 2, 3])
    assert (documented > 0.05).all(), documented
    for order in itertools.permutations(range(4)):
        if order != (0, 1, 2, 3):
            assert correlations(list(order)).sum() < documented.sum(), order
    # a flipped yaw sign convention turns the yaw correlation negative
    G_flipped = u2 @ (-torque_rows[2])
    assert np.corrcoef(J_alpha[:, 2], G_flipped)[0, 1] < 0


# per shipped vehicle with measured flights: its set, and flights long enough for the paired comparison
# (>= MIN_BLOCKS s airborne: the brushed figure-8s) beside the short brushless ones (the Fisher rule alone)
MEASURED = [("crazyflie21_brushless", "brushless_flights", ["eckart00", "eckart12", "eckart27"]),
            ("crazyflie21_brushless_pwm", "brushless_flights", ["eckart06"]),
            ("crazyflie21_brushless_payload", "brushless_flights_payload", ["eckart06", "eckart67"]),
            ("crazyflie21_brushless_payload_total", "brushless_flights_payload", ["eckart30"]),
            ("crazyflie21_brushed", "brushed_flights", ["jana00", "jana01", "jana04", "jana10"])]


@pytest.mark.parametrize("vehicle, folder, flights", MEASURED, ids=[m[0] for m in MEASURED])
def test_the_layout_check_passes_every_shipped_vehicles_measured_flights(vehicle, folder, flights):
    from qr import conventions
    from qr.ingest import read_log
    from qr.vehicle import load_vehicle

    v = load_vehicle(VEHICLES / f"{vehicle}.yaml")
    for name in flights:
        r = conventions.check_rotor_layout(conventions._pieces(read_log(DATA / folder / "data" / name, v), v), v)
        assert r.passed and r.measured.endswith(": the file's layout fits"), (name, r.measured)


def test_every_shipped_vehicle_with_a_layout_has_its_measured_flights_checked():
    shipped = {p.stem for p in VEHICLES.glob("*.yaml")} - {"asctec_hummingbird"}  # (no measured flights)
    assert shipped == {m[0] for m in MEASURED}
