"""Learning data: input groups and labels from the physics, splits that cannot leak, leakage flags."""

import numpy as np
import pandas as pd
import pytest

from learning_data import random_table
from qr import datasets
from qr.errors import QrInputError


def _time_table(durations, rate=100.0):
    """flight + t only (all a split looks at), flights one after the other."""
    parts = [pd.DataFrame({"flight": f"f{i}", "t": 10.0 + np.arange(int(d * rate)) / rate})
             for i, d in enumerate(durations)]
    return pd.concat(parts, ignore_index=True)


def _assert_no_leak(table, sp, gap=0.0):
    parts = {"train": sp.train, "val": sp.val, "test": sp.test}
    for name, idx in parts.items():
        assert np.all(np.diff(idx) > 0), f"{name} not in order"  # never shuffled
    for a in parts:
        for b in parts:
            if a < b:
                assert not set(parts[a]) & set(parts[b]), f"{a} and {b} overlap"
    # time order within every flight: train, then validation, then test, each gap apart
    for flight, rows in table.groupby("flight").groups.items():
        t = {k: table.loc[sorted(set(rows) & set(v)), "t"] for k, v in parts.items()}
        order = [k for k in ("train", "val", "test") if len(t[k])]
        for a, b in zip(order, order[1:]):
            assert t[b].min() - t[a].max() >= gap - 1e-9, (flight, a, b)


def test_groups_are_the_physical_signals(hummingbird):
    """v_b is the world velocity in the body frame, q maps back to R with qw >= 0, u2 = u^2, p_z the height."""
    from qr.sim.synth import SynthConfig, simulate_truth
    from qr.states import signals

    truth = simulate_truth(hummingbird, [], SynthConfig(duration=4.0, seed=3))
    s = signals(truth)
    X = datasets.features(s, ["v_b", "q", "u2", "p_z"])
    assert X.shape == (len(truth), 3 + 4 + 4 + 1)
    assert datasets.columns(["v_b", "q", "u2", "p_z"])[:5] == ["v_b.x", "v_b.y", "v_b.z", "q.w", "q.x"]
    R = s.R
    v_w = truth[["vx", "vy", "vz"]].to_numpy()
    np.testing.assert_allclose(np.einsum("nij,ni->nj", R, v_w), X[:, :3], atol=1e-12)
    q = X[:, 3:7]
    assert (q[:, 0] >= 0).all()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1, atol=1e-12)
    from scipy.spatial.transform import Rotation

    np.testing.assert_allclose(Rotation.from_quat(q, scalar_first=True).as_matrix(), R, atol=1e-9)
    np.testing.assert_allclose(X[:, 7:11], truth[["u1", "u2", "u3", "u4"]].to_numpy() ** 2)
    np.testing.assert_allclose(X[:, 11], truth["pz"])


def test_labels_of_a_hidden_drag_are_the_drag(hummingbird):
    """On noise-free truth, f_a is exactly the hidden -diag(k) v_b and tau_a is zero."""
    from qr.effects import parse_effect_spec
    from qr.sim.synth import SynthConfig, simulate_truth

    truth = simulate_truth(hummingbird, [parse_effect_spec("linear_drag:kx=0.3,ky=0.2,kz=0.1")],
                           SynthConfig(duration=5.0, seed=2))
    table = datasets.flight_table(truth, hummingbird, "truth")
    X, y = datasets.xy(table, ["v_b"], "f_a")
    np.testing.assert_allclose(y, -X * np.array([0.3, 0.2, 0.1]), atol=1e-6)
    _, tau = datasets.xy(table, ["v_b"], "tau_a")
    assert np.abs(tau).max() < 1e-6
    assert list(table.columns[:3]) == ["flight", "t", "v_b.x"]


def test_leakage_flags():
    assert datasets.leaks_target("f_a", ["v_b", "a_b", "u"])
    assert datasets.leaks_target("tau_a", ["q", "omega", "alpha", "u"])
    assert not datasets.leaks_target("f_a", ["v_b", "q", "omega", "alpha", "u"])  # alpha is not in eq. 4.34
    assert not datasets.leaks_target("tau_a", ["v_b", "a_b", "u"])  # a_b is not in eq. 4.39


def test_unknown_group_or_target_is_one_clear_error():
    with pytest.raises(QrInputError, match="unknown input group 'v_bb'.*did you mean 'v_b'"):
        datasets.features(None, ["v_bb"])
    with pytest.raises(QrInputError, match="unknown target 'f'"):
        datasets.leaks_target("f", ["v_b"])
    with pytest.raises(QrInputError, match="repeat"):
        datasets.check_inputs(["v_b", "v_b"])


def test_thesis_split_is_the_thesis_windows():
    table = _time_table([60.0])
    sp = datasets.split(table, {"kind": "thesis"})
    np.testing.assert_array_equal(sp.train, np.arange(1500, 2550))  # 70 % of 1500-3000
    np.testing.assert_array_equal(sp.val, np.arange(2550, 2775))
    np.testing.assert_array_equal(sp.inner_test, np.arange(2775, 3000))
    np.testing.assert_array_equal(sp.test, np.arange(3000, 4500))
    _assert_no_leak(table, sp)
    with pytest.raises(QrInputError, match="needs 4500 samples.*have 3000"):
        datasets.split(_time_table([30.0]), {"kind": "thesis"})


@pytest.mark.parametrize("gap", [1.0, 2.5])
def test_blocked_split_keeps_gaps_and_time_order(gap):
    table = _time_table([20.0, 12.0, 8.0])
    sp = datasets.split(table, {"kind": "blocked", "gap_s": gap})
    _assert_no_leak(table, sp, gap=gap)
    assert len(sp.train) > 2 * len(sp.test) > 0
    for part in (sp.train, sp.val, sp.test):  # one contiguous stretch per flight
        for _, rows in table.iloc[part].groupby("flight").groups.items():
            assert rows.max() - rows.min() + 1 == len(rows)
    assert set(sp.windows["test"]) == {"f0", "f1", "f2"}


def test_by_flight_split_holds_out_whole_flights():
    table = random_table(flights=10, n=50)
    sp = datasets.split(table, {"kind": "by_flight", "seed": 4})
    names = {k: set(table["flight"].iloc[getattr(sp, k)]) for k in ("train", "val", "test")}
    assert not (names["train"] & names["test"] or names["train"] & names["val"] or names["val"] & names["test"])
    assert len(names["test"]) == 2 and len(names["val"]) == 2 and len(names["train"]) == 6
    _assert_no_leak(table, sp)
    again = datasets.split(table, {"kind": "by_flight", "seed": 4})
    np.testing.assert_array_equal(sp.test, again.test)  # seeded
    explicit = datasets.split(table, {"kind": "by_flight", "test_flights": ["f03"], "val_flights": ["f07"]})
    assert set(table["flight"].iloc[explicit.test]) == {"f03"}
    assert set(table["flight"].iloc[explicit.val]) == {"f07"}
    with pytest.raises(QrInputError, match="at least 3 flights.*split=blocked"):
        datasets.split(random_table(flights=2, n=50), {"kind": "by_flight"})


def test_bad_split_options_are_one_clear_error():
    table = _time_table([10.0])
    with pytest.raises(QrInputError, match="unknown split 'random'"):
        datasets.split(table, {"kind": "random"})
    with pytest.raises(QrInputError, match="no option.*'shuffle'"):
        datasets.split(table, {"kind": "blocked", "shuffle": True})
    with pytest.raises(QrInputError, match="fractions"):
        datasets.split(table, {"kind": "blocked", "fractions": [0.5, 0.5, 0.5]})


def test_table_round_trip(tmp_path):
    table = random_table(flights=2, n=20)
    datasets.write_table(table, tmp_path / "t.parquet")
    back = datasets.read_table(tmp_path / "t.parquet")
    pd.testing.assert_frame_equal(back, table)
    X, y = datasets.xy(back, ["v_b", "u"], "f_a")
    assert X.shape == (40, 7) and y.shape == (40, 3)
    with pytest.raises(QrInputError, match="does not exist"):
        datasets.read_table(tmp_path / "missing.parquet")
