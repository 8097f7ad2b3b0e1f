"""A fixed subset of the combinations benchmark (benchmarks/combinations.py, 44 random scenarios).

The cases the issue reported from an independent simulator: a force effect with a per-rotor one (which
drew spurious torque-side names and missed the motor imbalance), a pure actuator delay (which drew an
inertia error), and the delay beside force, per-rotor and inertia effects.  Each 60 s flight must name
exactly the hidden set (up to a confounding the diagnosis reports, as the spec asks), and the same set
with the same parameters on another machine's arithmetic (tests/decisions.py).
"""

import pytest

from decisions import assert_same_decisions, diagnose_elsewhere
from qr.sim.scenarios import combinations, diagnose_scenario, up_to_confounding

SUBSET = [2, 9, 13, 14, 22, 31, 41]
SCENARIOS = combinations()


@pytest.mark.parametrize("i", SUBSET, ids=["+".join(SCENARIOS[i].effects) for i in SUBSET])
def test_the_hidden_set_is_named(i, tmp_path):
    sc = combinations()[i]
    doc = diagnose_scenario(sc, tmp_path)
    ok, false = up_to_confounding(doc["effects"], sc.names)
    assert ok and not false, ([e["name"] for e in doc["effects"]], sc.names, doc["selection"]["path"])
    s = tmp_path / "s"
    assert_same_decisions(doc, diagnose_elsewhere([s / "flight.csv"], s / "vehicle.yaml", tmp_path / "there", case=i))
    for e in doc["effects"]:  # named true effects carry their parameters within 4 s.e. or 20 %
        truth = {t["name"]: t for t in sc.effects}.get(e["name"])
        for p, v in (truth or {}).get("parameters", {}).items():
            err = abs(e["parameters"][p] - v)
            assert err <= max(4 * e["stderr"][p], 0.2 * abs(v)), (e["name"], p, e["parameters"][p], v)
