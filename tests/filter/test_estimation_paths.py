"""The compiled fast path equals the filterpy reference to 1e-9, filters and smoothers alike.

Input: a synthetic flight with jittered (irregular) stamps, mocap dropouts,
and rotor 3 dropping out on its own (so the rotors do not share one
covariance).  Every column of the state table is compared, relative to the
column's magnitude.  For the smoothers the first 0.25 s (~25 samples) are
left out: in the diffuse start the backward pass subtracts covariances up to
~1e8 times the settled ones, so there either path carries only 7-9
significant digits (measured: up to 4e-8 on the smoothed α and u̇ variances,
3e-9 on u̇; after it, below 1e-9 everywhere).
"""

import numpy as np
import pytest

from conftest import VEHICLES
from qr.estimation import estimate
from qr.sim.synth import SynthConfig, synthesize
from qr.tracking import flatten
from qr.vehicle import load_vehicle

TOL = 1e-9


@pytest.fixture(scope="module")
def flight():
    v = load_vehicle(VEHICLES / "asctec_hummingbird.yaml")
    fl, _ = synthesize(v, [], SynthConfig(duration=12.0, rate=100.0, seed=4))
    rng = np.random.default_rng(1)
    fl["t"] = fl["t"] + rng.uniform(-0.003, 0.003, len(fl))  # radio jitter: irregular dt
    fl.loc[rng.random(len(fl)) < 0.03, "u3"] = np.nan
    assert fl["px"].isna().any() and np.ptp(np.diff(fl["t"])) > 0.005
    return fl, v


CONFIGS = {
    "thesis": {},
    "thesis_smoother": {"smoother": True},
    "exact_smoother": {"discretisation": "exact", "smoother": True, "position": {"q": 50.0, "r": 2.5e-7},
                       "attitude": {"q": 40.0, "r": 9e-6}, "motor": {"q": 5e9, "r": 3000.0}},
}


@pytest.mark.parametrize("name", list(CONFIGS))
def test_fast_path_equals_reference(flight, name):
    fl, v = flight
    fast, rep_f = estimate(fl, v, {**CONFIGS[name], "implementation": "fast"})
    ref, rep_r = estimate(fl, v, {**CONFIGS[name], "implementation": "reference"})
    assert list(fast.columns) == list(ref.columns)
    smooth = CONFIGS[name].get("smoother", False)
    rows = (ref["t"] - ref["t"].iloc[0]).to_numpy() > 0.25 if smooth else slice(None)
    worst = {}
    for c in ref.columns:
        a, b = ref[c].to_numpy(), fast[c].to_numpy()
        assert np.array_equal(np.isnan(a), np.isnan(b)), c
        scale = np.nanmax(np.abs(a[rows])) or 1.0
        worst[c] = np.nanmax(np.abs(a[rows] - b[rows])) / scale
    print(f"\n{name}: largest relative difference fast vs reference: "
          + ", ".join(f"{c} {worst[c]:.1e}" for c in sorted(worst, key=worst.get)[-4:]))
    assert max(worst.values()) < TOL, {c: w for c, w in worst.items() if w >= TOL}
    flat_f, flat_r = flatten(rep_f.nis.to_json()), flatten(rep_r.nis.to_json())
    assert flat_f.keys() == flat_r.keys()
    for k, val in flat_r.items():
        assert flat_f[k] == (pytest.approx(val, rel=TOL) if isinstance(val, float) else val), k
