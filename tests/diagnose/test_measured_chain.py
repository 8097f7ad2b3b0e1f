"""Regression of the measured chain on a small fixed subset of the IMRCLab Crazyflie flights.

The engineer's chain of the workflow (conf/workflow.yaml, key `diagnose`): diagnose brushless flights
without payload, carry their extended vehicle over to the payload frame (its own mass, the payload left
out), hold the thrust map fixed there, and diagnose the payload flights.  The 4.7 g payload hanging
from a cable must be named, as a force along body or world z (mass_error, body_force_bias or
wind_force: on these flights the data do not separate them firmly, see the README), worth 2-7 g of
weight: the weighed 4.7 g, give or take the first set's thrust offset, which is confounded with its
mass (about +1.7 g of mass on the 37 g vehicle, README).  Exploratory measured results otherwise; this
is the part of them the project stands behind.  Both diagnoses are repeated on another machine's
arithmetic (tests/decisions.py): the same names, the same parameters.
"""

import pytest

from conftest import DATA, VEHICLES
from decisions import assert_same_decisions, diagnose_elsewhere
from qr.stages.diagnose import run_diagnosis
from qr.stages.diagnose_sets import carry_over
from qr.stages.ingest import ingest
from qr.vehicle import load_vehicle

BRUSHLESS = ["eckart00", "eckart06", "eckart12", "eckart17", "eckart22", "eckart27"]  # one per time scale
PAYLOAD = ["eckart06", "eckart12", "eckart20", "eckart43", "eckart51", "eckart67"]  # figure-8s and sideways
OVERRIDES = ["diagnose.block_s=1.0", "diagnose.gap_s=0.5", "diagnose.horizon_s=0.5"]
G = 9.81


@pytest.mark.skipif(not DATA.exists(), reason="measured data not available")
def test_the_payload_is_named_after_the_no_payload_model_is_carried_over(tmp_path):
    brushless, payload = VEHICLES / "crazyflie21_brushless.yaml", VEHICLES / "crazyflie21_brushless_payload.yaml"
    flights = {}
    for name, folder, flist, vehicle in (("b", "brushless_flights", BRUSHLESS, brushless),
                                        ("p", "brushless_flights_payload", PAYLOAD, payload)):
        (tmp_path / name).mkdir()
        flights[name] = [tmp_path / name / f"{f}.parquet" for f in flist]
        for f, out in zip(flist, flights[name]):
            ingest(DATA / folder / "data" / f, load_vehicle(vehicle), out)
    first = run_diagnosis(flights["b"], brushless, tmp_path / "first", OVERRIDES, log=lambda m: None, figures=False)
    assert "blade_flapping" in [e["name"] for e in first["effects"]]  # on every brushless flight alone, too
    assert_same_decisions(first, diagnose_elsewhere(flights["b"], brushless, tmp_path / "first_there", OVERRIDES))
    carry_over(tmp_path / "first" / "extended_vehicle.yaml", payload, tmp_path / "carried.yaml")
    second = OVERRIDES + ["diagnose.exclude=[thrust_gain,motor_imbalance]"]
    doc = run_diagnosis(flights["p"], tmp_path / "carried.yaml", tmp_path / "payload", second, log=lambda m: None,
                        figures=False)
    carry_over(tmp_path / "first_there" / "extended_vehicle.yaml", payload, tmp_path / "carried_there.yaml")
    assert_same_decisions(doc, diagnose_elsewhere(flights["p"], tmp_path / "carried_there.yaml",
                                                  tmp_path / "payload_there", second, case=1))
    named = {e["name"]: e["parameters"] for e in doc["effects"]}
    z_force = {"mass_error": lambda p: p["dm"] * G, "body_force_bias": lambda p: -p["bz"],
               "wind_force": lambda p: -p["fz"]}
    found = [e for e in named if e in z_force]
    assert len(found) == 1, doc["effects"]
    grams = z_force[found[0]](named[found[0]]) / G * 1000
    assert 2.0 <= grams <= 7.0, (found, grams)
