"""The slow torque balance (qr.diagnose.slow_torque): inertia judged on the residual summed over a horizon.

Hand-built sums first (window arithmetic, the slope, its s.e., the rule), then
a synthetic flight with an inertia error hidden, where the balance must return
the hidden dJ within its s.e. and leave the untouched axis alone.
"""

import numpy as np
import pytest

from qr.stages.diagnose import run_diagnosis
from qr.diagnose.slow_torque import slow_inertia, slow_torque, window_sums
from test_diagnose import _synth


def test_window_sums_stay_inside_a_group_and_skip_missing_rows():
    x = np.array([[1.0], [2.0], [3.0], [4.0], [5.0], [np.nan], [7.0], [8.0]])
    group = np.array([0, 0, 0, 1, 1, 1, 1, 1])
    sums, first = window_sums(x, group, 2)
    # group 0: 1+2, 2+3; group 1: 4+5 (5+nan and nan+7 left out), 7+8
    assert sums[:, 0].tolist() == [3.0, 5.0, 9.0, 15.0]
    assert first.tolist() == [0, 1, 3, 6]


def _blocks(rng, k, noise, n_blocks=40, per=50):
    x = rng.normal(0, 1, (n_blocks * per, 3))
    y = k * x + rng.normal(0, noise, x.shape)
    return x, y, np.repeat(np.arange(n_blocks), per), n_blocks


BOUNDS = (np.full(3, -10.0), np.full(3, 10.0))


def test_a_slope_well_above_noise_is_named_with_the_least_squares_s_e():
    rng = np.random.default_rng(0)
    k = np.array([0.5, 0.0, -0.3])
    x, y, block, nb = _blocks(rng, k, 1.0)
    out = slow_inertia(x, y, block, nb, BOUNDS, folds=5, t_name=3.0, min_gain=0.05, n_boot=400, seed=1)
    se_ls = 1.0 / np.sqrt((x**2).sum(axis=0))  # independent rows: the textbook s.e. of a slope
    for a, o in enumerate(out):
        assert o.estimate == pytest.approx(k[a], abs=3 * se_ls[a])
        assert o.stderr == pytest.approx(se_ls[a], rel=0.3)
    assert [o.named for o in out] == [True, False, True]
    # explained share of the summed residual: k² var(x) / (k² var(x) + 1) for the named axes
    assert out[0].cv_gain == pytest.approx(0.25 / 1.25, abs=0.03)
    assert out[1].why_not.startswith("explains")


def test_an_axis_that_is_the_same_term_as_a_named_effect_is_not_tested():
    rng = np.random.default_rng(0)
    x, y, block, nb = _blocks(rng, np.array([0.5, 0.5, 0.5]), 1.0)
    out = slow_inertia(x, y, block, nb, BOUNDS, 5, 3.0, 0.05, 100, 1, skip={2: "the term of yaw_torque_gain"})
    assert [o.named for o in out] == [True, True, False]
    assert out[2].why_not == "the term of yaw_torque_gain" and out[2].estimate is None


def test_an_estimate_outside_the_plausible_range_is_not_named():
    rng = np.random.default_rng(0)
    x, y, block, nb = _blocks(rng, np.array([0.5, 0.5, 0.5]), 1.0)
    out = slow_inertia(x, y, block, nb, (np.full(3, -0.1), np.full(3, 0.1)), 5, 3.0, 0.05, 100, 1)
    assert not any(o.named for o in out) and all("plausible" in o.why_not for o in out)


@pytest.fixture(scope="module")
def hidden_inertia(tmp_path_factory):
    """Hummingbird, J_xx and J_yy 40 % above the file, J_zz as the file; high mocap noise."""
    from test_diagnose import NOISE_LEVELS

    tmp = tmp_path_factory.mktemp("slow")
    vehicle, _ = _synth(tmp, ["inertia_error:dJxx=0.0028,dJyy=0.0028,dJzz=0"], noise=NOISE_LEVELS["high"],
                        duration=60)
    return tmp, vehicle


def test_a_hidden_inertia_error_is_recovered_from_the_summed_residual(hidden_inertia):
    tmp, vehicle = hidden_inertia
    doc, res = run_diagnosis([tmp / "s" / "flight.csv"], tmp / "s" / "vehicle.yaml", tmp / "d",
                             log=lambda m: None, return_result=True, figures=False)
    fp = res.labels.cross
    slow = slow_torque(fp, vehicle, fp.y, 50, 5, 3.0, 0.05, 200, 0)
    roll, pitch, yaw = slow.axes
    for o in (roll, pitch):
        assert o.named and o.estimate == pytest.approx(0.0028, abs=3 * o.stderr), o
        assert o.stderr < 0.0028 / 5
    assert not yaw.named and "yaw_torque_gain" in yaw.why_not, yaw  # never tested as an inertia
    # the whole diagnosis names it (here the one-step selection already does)
    named = {e["name"]: e for e in doc["effects"]}
    assert "inertia_error" in named, doc["selection"]
    p = named["inertia_error"]["parameters"]
    assert p["dJxx"] == pytest.approx(0.0028, rel=0.2) and p["dJyy"] == pytest.approx(0.0028, rel=0.2)


def test_named_by_the_slow_balance_alone_the_file_keeps_the_untested_entry(hidden_inertia):
    """The one-step rule made unreachable (a 99 % loss cut asked): the balance names roll and pitch,
    Jzz stays the file's (stderr null, and the notes and the report say why)."""
    tmp, _ = hidden_inertia
    doc = run_diagnosis([tmp / "s" / "flight.csv"], tmp / "s" / "vehicle.yaml", tmp / "d2",
                        ["diagnose.selection.min_gain=0.99", "diagnose.selection.strong_gain=0.99"],
                        log=lambda m: None, figures=False)
    assert [e["name"] for e in doc["effects"]] == ["inertia_error"], doc["selection"]
    e = doc["effects"][0]
    assert e["parameters"]["dJxx"] == pytest.approx(0.0028, rel=0.2)
    assert e["parameters"]["dJyy"] == pytest.approx(0.0028, rel=0.2)
    assert e["parameters"]["dJzz"] == 0.0 and e["stderr"]["dJzz"] is None
    assert any("held at the vehicle file's value" in n for n in doc["notes"])
    axes = doc["selection"]["slow_torque"]["axes"]
    assert [a["named"] for a in axes] == [True, True, False]
    assert "Slow torque balance" in (tmp / "d2" / "report.md").read_text()
    assert doc["extended"]["torque_rmse"][0] < 0.5 * doc["nominal"]["torque_rmse"][0]
