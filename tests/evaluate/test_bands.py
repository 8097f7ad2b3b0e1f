"""Uncertainty bands of a rollout (:mod:`qr.bands`, docs/evaluate.md "Bands").

Flights whose TRUE thrust gain is drawn from a known normal distribution (σ = 1 %), flown noise-free by qr's
own plant: the Monte Carlo band drawn from that same covariance covers a flight's samples exactly when
|δ_true| lies within the draws' quantile of |δ| (the position and attitude deviation are, to first order,
|δ| times a window's own sensitivity), so the share covered is predicted from the δ's alone, without the
rollout; and over many flights it is 2Φ(q/σ) − 1.  A band drawn from a five times too narrow covariance
covers far less, and the scale chosen on other (validation) flights brings it back.  The ensemble's
members are resampled by whole flights; same seed ⇒ same bands, bit for bit, on any thread count; the
coverage reaches ``generalization.csv``; ``qr learn residual`` with members leaves the hybrid unchanged and
``qr evaluate`` draws its band.
"""

import json
import math

import numpy as np
import pytest
from scipy.stats import norm

from conftest import VEHICLES

H = 50
SIGMA = 0.01  # the true thrust gain's standard deviation
PARAM = [{"effect": "thrust_gain", "parameter": "gain", "label": "C_T (gain)", "shared_with": [], "written": 1.0,
          "bounds": [0.5, 1.5]}]


def _vehicle():
    from qr.vehicle import load_vehicle

    return load_vehicle(VEHICLES / "asctec_hummingbird.yaml")


def _flights(vehicle, deltas, starts=4, seed=0):
    """One short noise-free piece per δ: the plant with thrust gain 1 + δ flown on rotor speeds that wander about
    hover (each rotor its own phase, so the attitude moves too); the truth and the start states are its states."""
    from qr.rollout import MODEL, Windows, roll_window
    from qr.sim.plant import true_params

    rng = np.random.default_rng(seed)
    n = H + starts + 1
    t = np.arange(n) * 0.01
    out = []
    for d in deltas:
        phase = rng.uniform(0, 2 * np.pi, 4)
        U = vehicle.hover_speed * (1 + 0.02 * np.sin(2 * np.pi * 1.5 * t[:, None] + phase[None, :]))
        P = true_params(vehicle, [{"name": "thrust_gain", "parameters": {"gain": 1.0 + d}}])
        X0 = np.zeros((n, 13))
        X0[0, 2], X0[0, 6] = 1.0, 1.0
        traj = np.empty((n - 1, 13))
        roll_window(t, X0, U, 0, n - 1, P, MODEL, np.zeros(3), traj, np.empty((4, 13)), np.empty(13), np.empty(13),
                    np.empty(13))
        X0[1:] = traj
        ok = np.zeros(n, bool)
        ok[:starts] = True
        out.append(Windows(t, X0, U, ok, X0[:, 0:3].copy(), X0[:, 6:10].copy(), X0[:, 3:6].copy(),
                           X0[:, 10:13].copy()))
    return out


def _source(sigma):
    from qr.bands import Source

    return Source("parameters", "test", None, "", tuple(PARAM), np.array([1.0]), np.array([[sigma ** 2]]),
                  np.array([[0.5, 1.5]]))


def _quantile(x, level):
    return float(np.quantile(np.abs(x), level))  # linear interpolation, as qr.bands


@pytest.fixture(scope="module")
def known():
    from qr import bands

    v = _vehicle()
    deltas = np.random.default_rng(7).normal(0.0, SIGMA, 240)
    pieces = _flights(v, deltas)
    return v, deltas, pieces


def test_the_monte_carlo_band_covers_what_the_known_parameter_noise_predicts(known):
    from qr import bands

    v, deltas, pieces = known
    src = _source(SIGMA)
    draws = 32
    Ps = src.plants(v, draws, seed=3)
    sp = bands.spread(pieces, Ps, H)
    # the draws the band flew, from the same generator: the prediction needs no rollout
    d = bands.draw_parameters(np.array([1.0]), np.array([[SIGMA ** 2]]), np.array([[0.5, 1.5]]), draws, 3)[:, 0] - 1
    from qr.plant_state import P_SCALE

    assert np.array_equal(Ps[1:, P_SCALE.start], 1.0 + d) and Ps[0, P_SCALE.start] == 1.0  # the plants flew these draws
    for level, r in ((0.5, sp.r50), (0.9, sp.r90)):
        q = _quantile(d, level)
        inside = np.abs(deltas) <= q
        clear = np.abs(np.abs(deltas) - q) > 0.05 * q  # flights not on the edge, where 2nd order decides
        for k in (0, 2):  # position, attitude
            covered = (sp.err[:, k] <= r[:, k]).reshape(len(deltas), -1)
            assert (covered[clear].all(axis=1) == inside[clear]).mean() > 0.98
            share = covered.mean()
            assert share == pytest.approx(inside.mean(), abs=0.03)
            # and the expectation over flights: 2Φ(q/σ) − 1 (binomial: ± 3 s.d.)
            expect = 2 * norm.cdf(q / SIGMA) - 1
            assert abs(share - expect) < 3 * math.sqrt(expect * (1 - expect) / len(deltas)) + 0.02
    # qr.bands.coverage says the same (its share of p at the 90 % level: the samples inside the radius)
    c = bands.coverage(sp, None)
    assert c["by_quantity"]["p"]["coverage90"] == pytest.approx((sp.err[:, 0] <= sp.r90[:, 0]).mean())


def test_a_too_narrow_band_is_scaled_on_validation_flights_and_then_covers(known):
    from qr import bands

    v, deltas, pieces = known
    narrow = _source(SIGMA / 5)
    Ps = narrow.plants(v, 32, seed=3)
    val_deltas = np.random.default_rng(8).normal(0.0, SIGMA, 240)
    val = bands.spread(_flights(v, val_deltas, seed=1), Ps, H)
    test = bands.spread(pieces, Ps, H)
    raw = bands.coverage(test, None)
    assert raw["by_quantity"]["p"]["coverage90"] < 0.5  # five times too narrow
    scale = bands.calibrate(val)
    # independent: the 90 % quantile of |δ_true| over the validation flights' samples, over the draws' quantile
    d = bands.draw_parameters(np.array([1.0]), np.array([[(SIGMA / 5) ** 2]]), np.array([[0.5, 1.5]]), 32, 3)[:, 0] - 1
    expect = np.quantile(np.repeat(np.abs(val_deltas), 4), 0.9) / _quantile(d, 0.9)
    assert scale["p"] == pytest.approx(expect, rel=0.05) and scale["R"] == pytest.approx(expect, rel=0.05)
    scaled = bands.coverage(test, scale)
    for q in ("p", "R"):
        assert 0.8 <= scaled["by_quantity"][q]["coverage90"] <= 0.97
    # the 50 % band's own scale: the median |δ_true| over the draws' median |δ|; it then covers about half
    scale90, scale50 = bands.calibrate_levels(val)
    assert scale90 == scale
    expect50 = np.quantile(np.repeat(np.abs(val_deltas), 4), 0.5) / _quantile(d, 0.5)
    assert scale50["p"] == pytest.approx(expect50, rel=0.05) and scale50["R"] == pytest.approx(expect50, rel=0.05)
    both = bands.coverage(test, scale, scale50)
    for q in ("p", "R"):
        assert 0.4 <= both["by_quantity"][q]["coverage50"] <= 0.6
        assert both["by_quantity"][q]["coverage90"] == scaled["by_quantity"][q]["coverage90"]


def test_draws_have_the_covariance_asked_and_stay_within_bounds():
    from qr.bands import draw_parameters

    cov = np.array([[4.0, 1.2], [1.2, 1.0]]) * 1e-4
    x = draw_parameters(np.array([0.0, 1.0]), cov, np.array([[-1, 1], [0.0, 2.0]]), 20000, seed=1)
    assert np.cov(x.T) == pytest.approx(cov, rel=0.05)
    # N(0, 1) restricted to ±a: its variance 1 − 2aφ(a) / (2Φ(a) − 1), 0.0806 at a = 0.5
    y = draw_parameters(np.array([0.0]), np.array([[1.0]]), np.array([[-0.5, 0.5]]), 2000, seed=1)
    assert -0.5 <= y.min() and y.max() <= 0.5
    a = 0.5
    assert y.var() == pytest.approx(1 - 2 * a * norm.pdf(a) / (2 * norm.cdf(a) - 1), rel=0.1)


def test_draws_near_a_bound_keep_what_the_covariance_ties():
    """Two terms the data see only as a sum (a thrust gain against a vertical force, say): their covariance
    keeps x₁ + x₂ within 0.001 while each moves by 0.1.  Written 0.02 above x₁'s lower bound, most draws would
    cross it; drawn again instead of clipped, every draw keeps the sum (clipped, the sum moved by up to the
    amount cut off, ~0.2: vehicles the covariance excludes)."""
    from qr.bands import draw_parameters

    sd, tie = 0.1, 0.001
    var_sum, var = tie ** 2, sd ** 2  # Var(x₁ + x₂) = 2 var + 2 c
    cov = np.array([[var, (var_sum - 2 * var) / 2], [(var_sum - 2 * var) / 2, var]])
    x = draw_parameters(np.array([0.02, 0.98]), cov, np.array([[0.0, 1.0], [0.0, 2.0]]), 500, seed=5)
    assert x.shape == (500, 2) and x[:, 0].min() >= 0.0
    assert np.abs(x.sum(axis=1) - 1.0).max() <= 5 * tie
    assert x[:, 0].std() > 0.3 * sd  # the terms still move apart, within the bound


def test_same_seed_same_bands_bits_on_any_thread_count(known):
    import numba

    from qr import bands

    v, _, pieces = known
    src = _source(SIGMA)
    a = bands.spread(pieces[:20], src.plants(v, 16, seed=5), H)
    n = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        b = bands.spread(pieces[:20], src.plants(v, 16, seed=5), H)
    finally:
        numba.set_num_threads(n)
    for f in ("err", "r50", "r90"):
        assert getattr(a, f).tobytes() == getattr(b, f).tobytes()
    c = bands.spread(pieces[:20], src.plants(v, 16, seed=6), H)
    assert c.r90.tobytes() != a.r90.tobytes()


def test_ensemble_members_are_resampled_by_whole_flights():
    from qr.ensemble import member_pieces, resample
    from qr.residual_fit import Piece

    flights = [f"f{k}.csv" for k in range(6)]
    draws = [resample(flights, seed=11, k=k) for k in range(5)]
    assert draws == [resample(flights, seed=11, k=k) for k in range(5)]  # same seed, same members
    assert len({json.dumps(d) for d in draws}) == 5  # each member its own draw
    for d in draws:
        assert set(d) <= set(flights) and sum(d.values()) == len(flights)
    # two pieces per flight, plus a validation flight never drawn
    parts = []
    for f in [*flights, "val.csv"]:
        for j in range(2):
            tr = np.arange(10) + 100 * j if f != "val.csv" else np.zeros(0, int)
            va = np.arange(5) + 100 * j if f == "val.csv" else np.zeros(0, int)
            parts.append(Piece(f, None, tr, va))
    for d in draws:
        seen = member_pieces(parts, d)
        by = {}
        for pc in seen:
            by.setdefault(pc.flight, []).append(len(pc.train))
        for f in flights:  # whole flights: every piece of a drawn flight, as often as drawn; none of the others
            assert sum(by[f]) == 20 * d.get(f, 0)
        assert sum(by["val.csv"]) == 0
        # validation windows once each, whatever was drawn
        assert sum(len(pc.val) for pc in seen) == 10


def test_the_coverage_reaches_the_generalization_table(tmp_path):
    from qr.bands import Spread, coverage
    from qr.report.generalization import Scored, table

    sp = Spread(np.array([[0.1, 0.1, 0.1, 0.1]] * 9 + [[5.0, 5, 5, 5]]), np.ones((10, 4)) * 0.05,
                np.ones((10, 4)) * 0.2, np.arange(10.0), np.zeros(10, int))
    cov = coverage(sp, None)  # 9 of 10 inside the 90 % radius, none inside the 50 % one
    assert cov["coverage90"] == 0.9 and cov["coverage50"] == 0.0

    def doc(n):
        blk = lambda x: {q: {"mae": [x] * H, "simerr": x * H, "windows": n} for q in "pvRw"}  # noqa: E731
        return {"horizon": H, "dt": 0.01, "labels": {"h.yaml": "hybrid (rollout-trained)"},
                "models": {"rate_frozen": blk(2.0), "h.yaml": blk(1.0)}, "bands": {"h.yaml": cov}}

    d2 = doc(10)
    d2["bands"] = {"h.yaml": coverage(Spread(sp.err, sp.r50, sp.r90 * 0, sp.t, sp.piece), None)}  # covers 0
    df = table([Scored("s", "trajectory", "a", (doc(10),), "g"), Scored("s", "trajectory", "b", (d2,), "g")])
    rows = df.set_index("held_out")["coverage90"]
    assert rows["a"] == 0.9 and rows["b"] == 0.0
    pooled = df[df["held_out"].str.contains("pooled")]["coverage90"].iloc[0]
    assert pooled == pytest.approx(0.45)  # 9 of 20 samples per quantity


def test_learn_residual_members_leave_the_hybrid_unchanged_and_evaluate_draws_the_band(tmp_path):
    from qr.sim.synth import SynthConfig, write_synth
    from qr.stages.evaluate import run_evaluation
    from qr.stages.learn_residual import run_residual

    v = _vehicle()
    for name, seed in (("a", 1), ("b", 2), ("c", 3), ("d", 4)):
        write_synth(tmp_path / name, v, [], SynthConfig(duration=12, rate=100, seed=seed))
    fl = [tmp_path / n / "flight.csv" for n in "abc"]
    tiny = ["learn.horizon=10", "learn.width=4", "learn.depth=1", "learn.epochs=1", "learn.stride=8"]
    quiet = lambda m: None  # noqa: E731
    run_residual(fl, tmp_path / "a" / "vehicle.yaml", tmp_path / "one", [*tiny, "learn.members=0"], track=False,
                 log=quiet)
    doc = run_residual(fl, tmp_path / "a" / "vehicle.yaml", tmp_path / "ens", [*tiny, "learn.members=2"],
                       track=False, log=quiet)
    assert (tmp_path / "one" / "residual.npz").read_bytes() == (tmp_path / "ens" / "residual.npz").read_bytes()
    assert not (tmp_path / "one" / "hybrid_vehicle.bands.json").exists()
    band = json.loads((tmp_path / "ens" / "hybrid_vehicle.bands.json").read_text())
    assert band["kind"] == "ensemble" and len(band["members"]) == 2 and doc["ensemble"]["members"] == 2
    val = doc["flights"]["validation"]
    for m in band["members"]:  # drawn from the training flights only, as many as there are
        assert not set(m["flights"]) & set(val) and sum(m["flights"].values()) == len(doc["flights"]["training"])
    ev = run_evaluation([tmp_path / "d" / "flight.csv"], [tmp_path / "a" / "vehicle.yaml",
                                                         tmp_path / "ens" / "hybrid_vehicle.yaml"],
                        tmp_path / "ev", ["evaluate.horizon=20"], log=quiet)
    b = ev["bands"]["hybrid_vehicle.yaml"]
    assert b["kind"] == "ensemble" and b["draws"] == 2 and 0 <= b["coverage90"] <= 1
    assert "vehicle.yaml" in ev["bands_none"]
    report = (tmp_path / "ev" / "report.md").read_text()
    assert "uncertainty bands" in report and (tmp_path / "ev" / "figures" / "bands.png").exists()


def test_each_band_gets_its_own_scale_when_the_spread_is_heavier_tailed_than_the_errors():
    """Draws that now and then diverge make r₉₀ ten times r₅₀ where the errors' own 90 % quantile is 2.4 times
    their median (|N(0, 1)|: 1.645 / 0.674): scaled for the 90 % band alone, the 50 % band covers a small
    share; with its own scale (the errors' median over r₅₀, by hand) it covers half, on other samples too."""
    from qr import bands

    rng = np.random.default_rng(4)

    def sample(n):
        err = np.abs(rng.normal(0.0, 1.0, (n, 4)))
        return bands.Spread(err, np.full((n, 4), 0.1), np.full((n, 4), 1.0), np.arange(n) * 0.01, np.zeros(n, int))

    val, test = sample(4000), sample(4000)
    s90, s50 = bands.calibrate_levels(val)
    for q in ("p", "v", "R", "w"):
        k = "pvRw".index(q)
        assert s90[q] == pytest.approx(np.quantile(val.err[:, k], 0.9) / 1.0)
        assert s50[q] == pytest.approx(np.quantile(val.err[:, k], 0.5) / 0.1)
    one = bands.coverage(test, s90)["by_quantity"]
    own = bands.coverage(test, s90, s50)["by_quantity"]
    for q in ("p", "v", "R", "w"):
        assert one[q]["coverage50"] < 0.15  # 0.1 × 1.645: P(|z| < 0.16) ≈ 0.13
        assert own[q]["coverage50"] == pytest.approx(0.5, abs=0.03)
        assert own[q]["coverage90"] == one[q]["coverage90"] == pytest.approx(0.9, abs=0.02)
