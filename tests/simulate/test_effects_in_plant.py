"""A hidden effect's residual, computed by qr.dynamics from the TRUE states, is its catalog term.

The plant implements each effect through its physics (true mass, inertia,
rotor scales, a delayed rotor map, a displaced marker, added forces); the
catalog writes the term the nominal model misses.  Agreement checks both.
"""

import numpy as np
import pytest

from conftest import signals_from_truth
from qr.dynamics import residuals
from qr.effects import CATALOG, parse_effect_spec, total_term
from qr.sim.synth import SynthConfig, simulate_truth
from qr.sim.trajectory import TrajectoryConfig

EFFECTS = {
    "linear_drag": "kx=0.3,ky=0.2,kz=0.1",
    "quadratic_drag": "cx=0.1,cy=0.15,cz=0.05",
    "rotor_drag": "k=1e-5",
    "wind_force": "fx=0.5,fy=-0.3,fz=0.2",
    "body_force_bias": "bx=0.1,by=-0.2,bz=0.3",
    "thrust_gain": "gain=1.08",
    "mass_error": "dm=0.05",
    "ground_effect": "k=0.005",
    "motor_imbalance": "d1=0.05,d2=-0.03,d3=0.02,d4=0.0",
    "cg_offset": "rx=0.01,ry=-0.005",
    "torque_bias": "tx=0.01,ty=-0.01,tz=0.005",
    "yaw_torque_gain": "gain=1.2",
    "inertia_error": "dJxx=0.001,dJyy=0.0015,dJzz=0.002",
    "marker_offset": "rx=0.02,ry=-0.01,rz=0.03",
    "blade_flapping": "k=0.02",
    "rotor_drag_moment": "k=1e-5",
    "translational_lift": "k=0.01",
}
CFG = SynthConfig(duration=20, seed=3, noise_free=True,
                  trajectory=TrajectoryConfig(low_passes=True, dip_every_s=6.0))


def test_every_catalog_effect_is_covered():
    assert set(EFFECTS) | {"actuator_delay"} == set(CATALOG)


@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_residual_equals_catalog_term(name, hummingbird):
    effect = parse_effect_spec(f"{name}:{EFFECTS[name]}")
    truth = simulate_truth(hummingbird, [effect], CFG)
    s = signals_from_truth(truth)
    r = residuals(s, hummingbird)
    term = total_term([effect], s, hummingbird)
    # the effect is present (well above integration error) ...
    assert np.abs(term).max() > 1e-4
    # ... and explains the residual to numerical precision on every axis
    np.testing.assert_allclose(r, term, atol=1e-10)
    # axes the catalog says it cannot touch stay clean
    untouched = [i for i in range(6) if i not in CATALOG[name].axes]
    np.testing.assert_allclose(r[:, untouched], 0.0, atol=1e-10)


def test_actuator_delay_is_first_order(hummingbird):
    errs = {}
    for d in (0.02, 0.01):
        effect = parse_effect_spec(f"actuator_delay:delay_s={d}")
        truth = simulate_truth(hummingbird, [effect], CFG)
        s = signals_from_truth(truth)
        r, term = residuals(s, hummingbird), total_term([effect], s, hummingbird)
        errs[d] = np.sqrt(((r - term)[:, 3:] ** 2).mean())
        rel = errs[d] / np.sqrt((term[:, 3:] ** 2).mean())
        assert rel < 0.15  # the first-order term carries most of the residual
    # the remainder is second order in the delay: halving it divides the error by ~4
    assert errs[0.02] / errs[0.01] > 3.0
