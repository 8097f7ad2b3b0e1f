"""The on-board gyro fused into the attitude ESKF (``filter.attitude.gyro``).

A synthetic flight gets a gyro made from the TRUE body rate plus a constant bias
and white noise of known size.  Fused, the rate and the angular acceleration
must come closer to the truth than from the mocap attitude alone, the bias and
the noise must be recovered, and the compiled path must equal the filterpy
reference (the gyro update in both is the Joseph-form update with
``H = [[ω̂_b]×, R̂ᵀ, 0, 0]``).
"""

import numpy as np
import pytest

from conftest import VEHICLES
from qr.estimation import estimate
from qr.sim.synth import SynthConfig, synthesize
from qr.vehicle import load_vehicle

BIAS = np.array([0.01, -0.02, 0.005])  # rad/s
SD = 0.02  # rad/s
W, AL = ["wx", "wy", "wz"], ["alx", "aly", "alz"]
TUNED = {"smoother": True, "discretisation": "exact", "tune": {"enabled": True}}


@pytest.fixture(scope="module")
def flight():
    v = load_vehicle(VEHICLES / "asctec_hummingbird.yaml")
    fl, truth = synthesize(v, [], SynthConfig(duration=20.0, rate=100.0, seed=5))
    rng = np.random.default_rng(3)
    fl[["gx", "gy", "gz"]] = truth[W].to_numpy() + BIAS + rng.normal(0, SD, (len(fl), 3))
    fl.loc[rng.random(len(fl)) < 0.02, ["gx", "gy", "gz"]] = np.nan
    return fl, truth, v


def _rmse(st, truth, cols, skip=1.0):
    k = (st["t"] - st["t"].iloc[0]).to_numpy() > skip
    return np.sqrt(np.mean((st[cols].to_numpy()[k] - truth[cols].to_numpy()[k]) ** 2, axis=0))


def test_the_gyro_brings_rate_and_acceleration_closer_to_the_truth(flight):
    fl, truth, v = flight
    alone, rep0 = estimate(fl, v, TUNED)
    fused, rep = estimate(fl, v, {**TUNED, "attitude": {"gyro": True}})
    assert rep0.gyro == {"fused": False}
    g = rep.gyro
    assert g["fused"] and g["samples"] == int(fl["gx"].notna().sum())
    assert np.allclose(g["bias"], BIAS, atol=3e-3), g["bias"]
    assert g["noise_sd"] == pytest.approx(SD, rel=0.15)
    w0, w1 = _rmse(alone, truth, W), _rmse(fused, truth, W)
    a0, a1 = _rmse(alone, truth, AL), _rmse(fused, truth, AL)
    print(f"\nω RMSE mocap only {w0.round(4)}, fused {w1.round(4)}; α RMSE {a0.round(3)} -> {a1.round(3)}")
    assert np.all(w1 < 0.8 * w0) and np.all(a1 < a0)
    # a fused rate is better than the gyro itself (its noise averaged with the attitude's)
    assert np.all(w1 < SD)
    # the attitude does not get worse
    q0 = _rmse(alone, truth, ["qx", "qy", "qz"])
    assert np.all(_rmse(fused, truth, ["qx", "qy", "qz"]) < 1.1 * q0)


def test_without_gyro_columns_the_setting_changes_nothing(flight):
    fl, _, v = flight
    plain = fl.drop(columns=["gx", "gy", "gz"])
    a, rep = estimate(plain, v, {"attitude": {"gyro": True}})
    b, _ = estimate(plain, v, {})
    assert rep.gyro == {"fused": False}
    assert np.array_equal(a[W].to_numpy(), b[W].to_numpy())


@pytest.mark.parametrize("smoother", [False, True])
def test_fast_path_equals_reference_with_the_gyro(flight, smoother):
    fl, _, v = flight
    cfg = {"smoother": smoother, "discretisation": "exact", "attitude": {"q": 40.0, "r": 9e-6, "gyro": True}}
    fast, _ = estimate(fl.iloc[:600].reset_index(drop=True), v, {**cfg, "implementation": "fast"})
    ref, _ = estimate(fl.iloc[:600].reset_index(drop=True), v, {**cfg, "implementation": "reference"})
    rows = (ref["t"] - ref["t"].iloc[0]).to_numpy() > 0.25
    for c in ["qw", "qx", "qy", "qz", *W, *AL, "sd_wx", "sd_alx"]:
        a, b = ref[c].to_numpy()[rows], fast[c].to_numpy()[rows]
        assert np.max(np.abs(a - b)) <= 1e-9 * (np.max(np.abs(a)) or 1.0), c
