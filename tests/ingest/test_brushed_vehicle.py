"""The brushed Crazyflie's vehicle file (conf/vehicle/crazyflie21_brushed.yaml) against its logs.

No brushed C_T is documented; the file's comes from the hover balance of the workflow's TRAINING
flights (every third flight of the data set's brushed list held out): recomputed here from the raw logs,
and checked against a hand-made balance on one flight.  The held-out flights are never read.
"""

import numpy as np
import pytest
import yaml

from conftest import DATA, ROOT, VEHICLES

pytestmark = pytest.mark.skipif(not (DATA / "brushed_flights" / "data").is_dir(), reason="measured data not present")


def _brushed():
    sets = yaml.safe_load((ROOT / "conf" / "data" / "imrclab_crazyflie.yaml").read_text())["sets"]
    return sets["brushed"]


def test_the_brushed_thrust_coefficient_is_the_training_flights_hover_balance():
    from qr.airborne import hover_thrust_coeff
    from qr.ingest.cf_usd import read
    from qr.holdout import held_out_by_flight
    from qr.vehicle import load_vehicle

    s = _brushed()
    assert s["vehicle"] == "crazyflie21_brushed"
    train, test = held_out_by_flight(s["flights"])
    assert test == ["jana02", "jana06"]  # as the vehicle file says
    v = load_vehicle(VEHICLES / "crazyflie21_brushed.yaml")
    assert v.mass == 0.0347  # brushed_flights/README.md
    flights = [read(DATA / s["dir"] / f) for f in train]
    ct, each = hover_thrust_coeff(flights, v)
    assert v.thrust_coeff == pytest.approx(ct, rel=1e-6)
    assert np.ptp(each) / ct < 0.02  # the flights agree with each other
    assert v.torque_coeff == pytest.approx(0.006 * v.thrust_coeff, rel=1e-6)
    # by hand on one flight: mean rotor thrust along world z over m g, the rows the vehicle flies (z > 0.2 m)
    df = flights[0]
    q = df[["qw", "qx", "qy", "qz"]].to_numpy()
    R33 = 1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2)  # unit quaternions
    u2 = (df[["u1", "u2", "u3", "u4"]].to_numpy() ** 2).sum(axis=1)
    ok = np.isfinite(u2) & np.isfinite(R33) & (df["pz"].to_numpy() > 0.2)
    assert v.thrust_coeff * np.mean(R33[ok] * u2[ok]) / (v.mass * 9.81) == pytest.approx(1.0, abs=0.01)
