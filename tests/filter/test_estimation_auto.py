"""filter=auto finds the true noise intensities, and the NIS report flags a filter that is wrong about them.

Two kinds of synthetic truth:

- flights drawn from the filters' own models (``estimation_data.model_flight``):
  the only data with a true PROCESS-noise intensity, so both ``q`` and ``r``
  are checked, on irregular stamps with dropouts;
- `qr synth` flights (a controller flying a smooth trajectory, no process
  noise to speak of): the true MEASUREMENT noise is the synth's noise setting.
"""

import numpy as np
import pytest

from estimation_data import model_flight
from qr.config import compose, to_dict
from qr.estimation import estimate, nis
from qr.errors import QrInputError
from qr.sim.synth import NoiseConfig, SynthConfig, synthesize

TRUE = {"position": {"q": 4.0e3, "r": 2.5e-7}, "attitude": {"q": 6e-4, "r": 4e-8}, "motor": {"q": 2.0e12, "r": 2500.0}}


@pytest.fixture(scope="module")
def model():
    flight, truth = model_flight(seed=0, duration=20.0, q_pos=TRUE["position"]["q"], r_pos=TRUE["position"]["r"],
                                 q_att=TRUE["attitude"]["q"], r_att=TRUE["attitude"]["r"],
                                 q_mot=TRUE["motor"]["q"], r_mot=TRUE["motor"]["r"])
    return flight


def auto_cfg():
    return to_dict(compose(["filter=auto"]))["filter"]


def test_auto_recovers_process_and_measurement_noise_of_the_model(model):
    _, report = estimate(model, None, auto_cfg())
    print()
    for f, true in TRUE.items():
        got = report.noise[f]
        print(f"{f}: q {got['q']:.3g} (true {true['q']:.3g}), r {got['r']:.3g} (true {true['r']:.3g}), "
              f"bandwidth {got['corner_hz']:.2f} Hz")
        assert 0.5 < got["q"] / true["q"] < 2, f
        assert 0.5 < got["r"] / true["r"] < 2, f
        assert not report.tuning[f]["at_bound"]


@pytest.mark.parametrize("vehicle", ["hummingbird", "crazyflie"])
def test_auto_recovers_the_measurement_noise_of_qr_synth_flights(vehicle, request):
    v = request.getfixturevalue(vehicle)
    noise = NoiseConfig(position_std=0.001, attitude_std=0.005, rotor_std=0.02, dropout=0.01)
    flight, _ = synthesize(v, [], SynthConfig(duration=40.0, rate=100.0, seed=7, noise=noise))
    _, report = estimate(flight, v, auto_cfg())
    true_r = {"position": noise.position_std**2, "attitude": noise.attitude_std**2,
              "motor": (noise.rotor_std * v.hover_speed) ** 2}
    print()
    for f, r in true_r.items():
        got = report.noise[f]["r"]
        print(f"{vehicle} {f}: r {got:.3g} (true {r:.3g}), q {report.noise[f]['q']:.3g}, "
              f"bandwidth {report.noise[f]['corner_hz']:.2f} Hz")
        assert 0.5 < got / r < 2, f


@pytest.mark.parametrize("scale, verdict", [(1.0, None), (0.1, "over-confident"), (10.0, "under-confident")])
def test_nis_flags_a_filter_with_the_wrong_noise(model, scale, verdict):
    """With the true q and r the NIS means sit in their 95 % band; with r off by 10x every filter is flagged."""
    cfg = {"discretisation": "exact", **{f: {"q": v["q"], "r": v["r"] * scale} for f, v in TRUE.items()}}
    _, report = estimate(model, None, cfg)
    stats = [report.nis.position, report.nis.attitude, report.nis.motor["all"]]
    if verdict is None:
        assert report.inconsistent == () and all(s.consistent for s in stats)
        assert all(s.band[0] < s.mean < s.band[1] for s in stats)
    else:
        assert set(report.inconsistent) == {"position", "attitude", "motor.u1", "motor.u2", "motor.u3",
                                               "motor.u4"}
        assert all(s.verdict.startswith(verdict) for s in stats)


def test_thesis_tuning_is_flagged_on_a_noisier_mocap(hummingbird):
    """The thesis's R = 0.0002² m² on a 0.5 mm-noise mocap: the position filter is over-confident."""
    flight, _ = synthesize(hummingbird, [], SynthConfig(duration=20.0, rate=100.0, seed=2))
    _, report = estimate(flight, hummingbird, {})
    assert "position" in report.inconsistent
    assert report.nis.position.mean > 3 * report.nis.position.band[1]


def test_nis_band_is_the_chi_square_band_of_the_mean():
    rng = np.random.default_rng(0)
    ok = nis.nis_stats(rng.chisquare(3, 20000), 3)
    assert ok.consistent and ok.band[0] < 3 < ok.band[1]
    assert abs(ok.outside_sample_band - 0.05) < 0.01
    assert not nis.nis_stats(1.05 * rng.chisquare(3, 20000), 3).consistent  # 5 % too large, n = 20000


def test_auto_needs_the_exact_discretisation():
    with pytest.raises(QrInputError, match="discretisation: exact"):
        estimate(model_flight(duration=1.0)[0], None, {"tune": {"enabled": True}})
