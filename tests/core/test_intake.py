"""The one intake (qr.intake): the cutting with the command's minimum length, the order of its checks, and the
rollout's estimate (no cross-fitting halves) equal to the one ``qr evaluate`` filters itself."""

from dataclasses import replace

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


@pytest.fixture(scope="module")
def report(gapped):
    """A report with a tuning record as the filter stage writes one (noise values other than the settings')."""
    v, flight, cfg = gapped
    return replace(estimate(flight, v, cfg)[1], tuning={
        "position": {"q": 40.0, "r": 1e-7}, "attitude": {"q": [900.0, 90.0, 300.0], "r": 2e-6},
        "motor": {"q": 3000.0, "r": 0.5}})


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


def test_the_rollout_estimate_is_the_one_qr_evaluate_filters_itself(gapped, report):
    """Given the filter stage's tuning record, the intake's full estimate (matched settings, no halves) has the
    same position, velocity, attitude and rate, bit for bit, as ``qr evaluate``'s own (the settings frozen with
    :func:`fixed_settings`): the rollout starts from those alone."""
    v, flight, cfg = gapped
    taken = take(["g.csv"], [flight], v, IntakeSettings(1.5, cfg, halves=False), reports=[report])
    for e in taken.estimates:
        assert e.halves is None
        own = estimate(e.rows, v, fixed_settings(cfg, report.tuning))[0]
        assert np.array_equal(e.states[MOTION].to_numpy(), own[MOTION].to_numpy())


def test_a_memo_reads_checks_and_estimates_each_flight_once_with_the_same_numbers(gapped, report, monkeypatch,
                                                                                   tmp_path):
    """Commands run one after another on the same flights (a workflow fold) share a :class:`Memo`: the file is
    read once, the flight checked once per vehicle of other physical properties (a vehicle with effects added
    shares the nominal one's checks), each segment estimated once (the diagnosis's cross-fitted estimate serves
    the rollout); the numbers are those of an intake without it, and what it hands out is a copy."""
    import qr.conventions
    import qr.estimation.crossfit
    import qr.flight
    from qr.intake import Memo, read_flights
    from qr.vehicle import vehicle_from_dict

    v, flight, cfg = gapped
    path = tmp_path / "g.parquet"
    flight.to_parquet(path)
    calls = {"read": 0, "check": 0, "filter": 0}

    def counted(name, fn):
        def wrapped(*a, **k):
            calls[name] += 1
            return fn(*a, **k)
        return wrapped

    monkeypatch.setattr(qr.flight, "read_flight", counted("read", qr.flight.read_flight))
    monkeypatch.setattr(qr.conventions, "require", counted("check", qr.conventions.require))
    monkeypatch.setattr(qr.estimation.crossfit, "prepare_flight", counted("filter", qr.estimation.crossfit.prepare_flight))
    diagnosis, rollout = IntakeSettings(1.5, cfg), IntakeSettings(1.5, cfg, halves=False)
    alone = [take([str(path)], read_flights([path]), v, s, reports=[report]) for s in (diagnosis, rollout)]
    assert calls == {"read": 2, "check": 2, "filter": 4}  # two segments used, each filtered per command

    calls.update(read=0, check=0, filter=0)
    memo = Memo()
    drag = vehicle_from_dict({**v.to_dict(), "effects": [{"name": "linear_drag",
                                                          "parameters": {"kx": 0.1, "ky": 0.1, "kz": 0.05}}]})
    shared = [take([str(path)], read_flights([path], memo), veh, s, reports=[report], memo=memo)
              for veh, s in ((v, diagnosis), (v, rollout), (drag, rollout))]
    assert calls == {"read": 1, "check": 1, "filter": 2}
    heavier = vehicle_from_dict({**v.to_dict(), "mass": v.mass * 1.2})
    take([str(path)], read_flights([path], memo), heavier, rollout, reports=[report], memo=memo)
    assert calls["check"] == 2 and calls["filter"] == 4  # another mass: checked and filtered again (its hover speed)

    for taken, own in zip(shared, [*alone, alone[1]]):
        assert [e.window for e in taken.estimates] == [e.window for e in own.estimates]
        for e, o in zip(taken.estimates, own.estimates):
            assert e.states.equals(o.states) and e.rows.equals(o.rows)
            assert (e.halves is None) == (o.halves is None)
            assert e.halves is None or all(h.equals(g) for h, g in zip(e.halves, o.halves))
        assert taken.flights.conventions == own.flights.conventions
    assert shared[1].estimates[0].states is not shared[2].estimates[0].states  # copies: a command may change its own
    assert read_flights([path], memo)[0] is not read_flights([path], memo)[0]
