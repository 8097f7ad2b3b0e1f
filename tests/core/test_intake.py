"""The one intake (qr.intake): the cutting with the command's minimum length, the order of its checks, and the
rollout's estimate (no cross-fitting halves) equal to the one ``qr evaluate`` filters itself."""

import numpy as np
import pytest

from conftest import VEHICLES
from qr.config import compose, to_dict
from qr.estimation import estimate, resolve
from qr.estimation.crossfit import fixed_settings
from qr.intake import IntakeSettings, take
from qr.sim.synth import SynthConfig, synthesize
from qr.vehicle import load_vehicle

MOTION = ["px", "py", "pz", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "wx", "wy", "wz"]


@pytest.fixture(scope="module")
def gapped():
    """12 s at 100 Hz with samples missing at 7.0-7.3 s and 8.3-8.6 s: segments of 7.0, 1.0 and 3.4 s."""
    v = load_vehicle(VEHICLES / "asctec_hummingbird.yaml")
    flight, _ = synthesize(v, [], SynthConfig(duration=12.0, rate=100.0, seed=3))
    t = flight["t"].to_numpy()
    keep = ~(((t > 7.0) & (t < 7.3)) | ((t > 8.3) & (t < 8.6)))
    cfg = to_dict(compose([]))["filter"]
    resolve(cfg)
    return v, flight[keep].reset_index(drop=True), cfg


def test_a_segment_shorter_than_the_minimum_is_cut_said_and_not_estimated(gapped):
    v, flight, cfg = gapped
    events = []
    taken = take(["g.csv"], [flight], v, IntakeSettings(1.5, cfg, halves=False), say=events.append,
                 require=lambda path, fs: events.append(f"require {path}: {len(fs.used)} used"),
                 on_checked=lambda: events.append("checked"))
    windows = [tuple(round(x, 2) for x in s.window) for s in taken.flights.split[0].segments]
    assert windows == [(0.0, 7.0), (7.3, 8.3), (8.6, 12.0)]
    assert [s.used for s in taken.flights.split[0].segments] == [True, False, True]
    assert [tuple(round(x, 2) for x in e.window) for e in taken.estimates] == [(0.0, 7.0), (8.6, 12.0)]
    # the checks per flight, then what was cut said, then (once) the hook, then the estimates
    first_estimate = next(i for i, e in enumerate(events) if e.startswith("estimates of"))
    assert events.index("require g.csv: 2 used") < events.index("checked") < first_estimate
    assert any("segment 7.30-8.30 s not used: lasts 1.00 s, shorter than the 1.50 s" in e for e in events)
    assert taken.flights.conventions[0].flight == "g.csv" and taken.flights.conventions[0].checks


def test_the_rollout_estimate_is_the_one_qr_evaluate_filters_itself(gapped):
    """Given the filter stage's tuning record, the intake's full estimate (matched settings, no halves) has the
    same position, velocity, attitude and rate, bit for bit, as ``qr evaluate``'s own (the settings frozen with
    :func:`fixed_settings`): the rollout starts from those alone."""
    v, flight, cfg = gapped
    # a tuning record as the filter stage writes one (noise values other than the settings')
    report = {"tuning": {"position": {"q": 40.0, "r": 1e-7}, "attitude": {"q": [900.0, 90.0, 300.0], "r": 2e-6},
                         "motor": {"q": 3000.0, "r": 0.5}}}
    taken = take(["g.csv"], [flight], v, IntakeSettings(1.5, cfg, halves=False), reports=[report])
    for e in taken.estimates:
        assert e.halves is None
        own = estimate(e.rows, v, fixed_settings(cfg, report))[0]
        assert np.array_equal(e.states[MOTION].to_numpy(), own[MOTION].to_numpy())
