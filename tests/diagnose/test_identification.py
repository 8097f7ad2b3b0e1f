"""The identification library on hand-built numbers: normal equations, regressor noise, selection steps."""

import numpy as np
import pytest

from qr.identification.normal_equations import BlockStats, Columns, at_bound, bounded_noise, regressor_noise, solve
from qr.identification.selection import (SelectionConfig, better, choose_size, consistent, pinned_down,
                                         resolve_equivalents, torque_arbitration)


def test_regressor_noise_correction_undoes_the_attenuation():
    """y = 2 x + e, the regressor seen through two independent noisy copies (the cross-fitting halves,
    sd 0.5 on a unit-variance x): least squares on the other half's copy gives 2 / (1 + 0.25) = 1.6;
    taking out the noise Gram measured by the copies' difference gives 2 back."""
    rng = np.random.default_rng(0)
    n = 200_000
    x = rng.standard_normal(n)
    xa, xb = x + 0.5 * rng.standard_normal(n), x + 0.5 * rng.standard_normal(n)
    ya, yb = 2 * x + 0.3 * rng.standard_normal(n), 2 * x + 0.3 * rng.standard_normal(n)
    # stacked as the diagnosis stacks them: labels of a with regressors of b, and the other way round
    G = np.array([[xb @ xb + xa @ xa]])
    h = np.array([xb @ ya + xa @ yb])
    assert solve(G, h)[0] == pytest.approx(1.6, abs=0.01)
    D = (xa - xb)[:, None, None] * np.eye(6)[None, :, :1]  # the column in one of the six rows
    w = np.zeros((n, 6))
    w[:, 0] = 1.0
    N = regressor_noise(D, w, np.zeros(n, dtype=int), 1).sum(axis=0)[0]  # the rows' sum, block 0
    assert N[0, 0] == pytest.approx(2 * 0.25 * 2 * n / 2, rel=0.01)  # both copies' noise variance, n samples
    assert solve(G - N, h)[0] == pytest.approx(2.0, abs=0.01)


def test_a_correction_larger_than_the_column_is_bounded():
    G = np.array([[[4.0, 0.0], [0.0, 1.0]]])
    N = np.array([[[8.0, 0.0], [0.0, 0.5]]])  # the first column would be "more noise than variance"
    Nb = bounded_noise(G, N, keep=0.1)
    assert Nb[0, 0, 0] == pytest.approx(0.9 * 4.0)
    assert Nb[0, 1, 1] == pytest.approx(0.5)  # a plausible correction is left alone


def _stats(G, h, s, effects, lb=None, ub=None):
    G, h, s = np.atleast_3d(G), np.atleast_2d(h), np.atleast_1d(s)
    return BlockStats(G, h, s, np.ones(len(s)), Columns.of(effects), lb, ub)


def test_a_bound_at_the_neutral_value_is_a_constraint_not_nonsense():
    """Drag cannot be negative: a fit pinned at kz = 0 (neutral) is an absent component, fine; a C_T gain
    pinned at 0.5 (away from neutral) is nonsense."""
    G = np.eye(3)[None]
    h = np.array([[0.3, 0.2, -0.1]])  # kz would be -0.1
    drag = _stats(G, h, [1.0], ["linear_drag"], np.zeros(3), np.full(3, 10.0))
    assert not at_bound(drag, ["linear_drag"])
    gain = _stats(np.eye(1)[None], np.array([[-0.9]]), [1.0], ["thrust_gain"], np.array([-0.5]), np.array([0.5]))
    assert at_bound(gain, ["thrust_gain"])


class FakeCV:
    """Validation losses given by hand: per fold for each set, a paired t per pair."""

    def __init__(self, folds: dict, t: dict, effects=("linear_drag", "wind_force", "mass_error", "thrust_gain")):
        self._folds, self._t = folds, t
        self.stats = type("S", (), {"cols": Columns.of(list(effects))})()

    def losses(self, S):
        return np.asarray(self._folds[tuple(sorted(S))], float)

    def loss(self, S):
        return float(self.losses(S).mean())

    def paired_t(self, worse, better, on=None):
        return self._t.get((tuple(sorted(worse)), tuple(sorted(better))), 0.0)


def test_a_gain_carried_by_one_fold_is_not_named_a_consistent_or_a_strong_one_is():
    """Fold losses (noise units) before and after one more effect, by hand:
    - 1 % better in every fold: consistent, named;
    - 0.9, 0.65, 1.2, -0.4, 8.1 % (the payload flights' marker_offset): 1.9 % on average and better in
      4 of 5 folds, but the median fold gains 0.9 % < min_gain: not consistent, and < strong_gain;
    - 12 % in 3 of 5 folds and 0 elsewhere (a marker's kinematics in fast turns): not consistent (median
      0), but 7.2 % on average, in most folds, with paired t 2.5: strong where it acts, named;
    - the same with t 1.5: not significant, not named."""
    cfg = SelectionConfig()
    base = np.full(5, 100.0)
    cases = {
        ("linear_drag",): base * (1 - 0.0101),
        ("wind_force",): base * (1 - np.array([0.009, 0.0065, 0.012, -0.004, 0.081])),
        ("mass_error",): base * (1 - np.array([0.12, 0.12, 0.12, 0.0, 0.0])),
    }
    cv = FakeCV({(): base, **cases}, {((), ("mass_error",)): 2.5})
    assert better(cv, ("linear_drag",), (), cfg)
    assert not better(cv, ("wind_force",), (), cfg)
    assert better(cv, ("mass_error",), (), cfg)
    cv._t[((), ("mass_error",))] = 1.5
    assert not better(cv, ("mass_error",), (), cfg)


def test_the_size_stops_where_one_more_effect_is_not_better():
    cfg = SelectionConfig()
    levels = [[(100.0, ())], [(10.0, ("wind_force",))], [(9.95, ("linear_drag", "wind_force"))]]
    folds = {(): [100.0] * 5, ("wind_force",): [10.0] * 5, ("linear_drag", "wind_force"): [9.95] * 5}
    k, path = choose_size(FakeCV(folds, {}), levels, cfg)
    assert k == 1 and [p["accepted"] for p in path] == [True, True, False]
    assert path[2]["gain"] == pytest.approx(0.005)


def test_equivalent_sets_name_the_simplest_and_report_what_it_swaps_for():
    """Two sets of one size the data cannot tell apart (0.4 % apart, paired t 0.8): the one with fewer
    parameters is named, the other effect is its confounded partner.  A set 3 % worse is not equivalent."""
    cfg = SelectionConfig()
    level = [(1.000, ("linear_drag", "thrust_gain")), (1.004, ("linear_drag", "wind_force")),
             (1.030, ("linear_drag", "mass_error"))]
    cv = FakeCV({}, {(("linear_drag", "wind_force"), ("linear_drag", "thrust_gain")): 0.8,
                     (("linear_drag", "mass_error"), ("linear_drag", "thrust_gain")): 0.5})
    named, confounded, equivalent, _ = resolve_equivalents(cv, level, lambda S: None, cfg, rows=None)
    assert named == ["linear_drag", "thrust_gain"]  # thrust_gain: 1 parameter, wind_force 3
    assert confounded == {"linear_drag": [], "thrust_gain": ["wind_force"]}
    assert [e["effects"] for e in equivalent] == [["linear_drag", "wind_force"]]


def test_a_c_t_and_a_mass_error_are_judged_on_the_torque_rows_alone():
    """They are the same term in force: a 3 % better total loss for the mass error (noise in the
    acceleration regressor, say) does not decide; the torque rows do (t -2.6: the C_T error's torque
    helps there)."""
    cfg = SelectionConfig()
    level = [(1.00, ("mass_error",)), (1.03, ("thrust_gain",))]
    torque = object()
    cv = FakeCV({}, {})
    cv.paired_t = lambda worse, better, on=None: (
        -2.6 if (on is torque and worse == ("thrust_gain",)) else 2.6 if on is torque else 3.0)
    named, confounded, _, _ = resolve_equivalents(cv, level, lambda S: None, cfg, rows={"torque": torque})
    assert named == ["thrust_gain"]
    cv.paired_t = lambda worse, better, on=None: 0.5 if on is torque else 3.0  # torque rows cannot tell
    named, confounded, _, _ = resolve_equivalents(cv, level, lambda S: None, cfg, rows={"torque": torque})
    assert named == ["thrust_gain"] and confounded["thrust_gain"] == ["mass_error"]  # catalog order


def _rows(Gf, hf, sf, Gt, ht, st, effects):
    """All-row, force-row and torque-row statistics of 20 identical blocks."""
    B = 20
    f = BlockStats(np.repeat(Gf[None], B, 0), np.repeat(hf[None], B, 0), np.full(B, sf), np.full(B, 100.0),
                   Columns.of(effects))
    t = BlockStats(np.repeat(Gt[None], B, 0), np.repeat(ht[None], B, 0), np.full(B, st), np.full(B, 100.0),
                   Columns.of(effects))
    rng = np.random.default_rng(1)
    for st_ in (f, t):  # a little block-to-block variation, for the paired t
        st_.s = st_.s * (1 + 0.01 * rng.standard_normal(B))
    a = BlockStats(f.G + t.G, f.h + t.h, f.s + t.s, f.n + t.n, Columns.of(effects))
    return a, (f, t)


def test_force_and_torque_rows_that_disagree_make_a_set_inconsistent():
    """One gain parameter on force rows (G 100, h -10: gain error -0.1) and torque rows (G 100, h -60:
    -0.6).  Jointly -0.35: the force rows' loss grows from 99 to 105.25 (6 %) and the torque rows' from
    64 to 70.25: inconsistent.  With agreeing rows (-0.1 and -0.12) the growth is < 1 %: consistent."""
    cfg = SelectionConfig()
    e = ["thrust_gain"]
    a, rows = _rows(np.array([[100.0]]), np.array([-10.0]), 100.0, np.array([[100.0]]), np.array([-60.0]), 100.0, e)
    assert "force and torque disagree" in consistent(a, rows, e, cfg)
    a, rows = _rows(np.array([[100.0]]), np.array([-10.0]), 100.0, np.array([[100.0]]), np.array([-12.0]), 100.0, e)
    assert consistent(a, rows, e, cfg) is None


def test_torque_rows_that_need_a_c_t_error_beyond_any_plausible_one_cannot_arbitrate():
    """Torque rows wanting a gain of 0.2 (below the 1/3 bound) while the force rows want 0.96."""
    lb, ub = np.array([-2 / 3]), np.array([2.0])
    f = BlockStats(np.ones((4, 1, 1)), np.full((4, 1), -0.04), np.ones(4), np.ones(4), Columns.of(["thrust_gain"]),
                   lb, ub)
    t = BlockStats(np.ones((4, 1, 1)), np.full((4, 1), -0.8), np.ones(4), np.ones(4), Columns.of(["thrust_gain"]),
                   lb, ub)
    arb = torque_arbitration((f, t))
    assert arb["thrust_gain"].force_rows == pytest.approx([0.96])
    assert arb["thrust_gain"].torque_rows == pytest.approx([0.2], abs=1e-6)
    assert torque_arbitration((f, f)) == {}


def _blocks(X, y, blocks=20):
    """Per-block normal equations of y on the columns of X, in ``blocks`` equal blocks."""
    parts = np.array_split(np.arange(len(y)), blocks)
    G = np.stack([X[i].T @ X[i] for i in parts])
    h = np.stack([X[i].T @ y[i] for i in parts])
    s = np.array([y[i] @ y[i] for i in parts])
    return G, h, s, np.array([len(i) for i in parts], float)


def test_two_effects_that_trade_off_along_one_column_are_not_both_named():
    """y = x1 + noise, a second column x2 = x1 + 1 % noise (a C_T error and a constant body-z force while
    the thrust barely changes).  Fitted together, the pair splits x1's coefficient along a direction the
    data barely fix: one of the two stays within 3 s.e. of no effect, so the pair is not named.  With an
    independent x2 that is really there (y = x1 + 0.5 x2), both are pinned down."""
    rng = np.random.default_rng(1)
    n = 4000
    x1 = rng.standard_normal(n)
    cfg = SelectionConfig(seed=0)
    e = ["rotor_drag", "blade_flapping"]
    x2 = x1 + 0.01 * rng.standard_normal(n)
    y = x1 + 0.5 * rng.standard_normal(n)
    G, h, s, cnt = _blocks(np.column_stack([x1, x2]), y)
    assert "not pinned down" in pinned_down(BlockStats(G, h, s, cnt, Columns.of(e)), e, cfg)
    x2 = rng.standard_normal(n)
    y = x1 + 0.5 * x2 + 0.5 * rng.standard_normal(n)
    G, h, s, cnt = _blocks(np.column_stack([x1, x2]), y)
    assert pinned_down(BlockStats(G, h, s, cnt, Columns.of(e)), e, cfg) is None


def test_an_effect_is_pinned_down_jointly_not_parameter_by_parameter():
    """A motor imbalance beside a body-z force: its common mode (all d_i equal) is the force's column,
    so every single d_i has a large s.e. (|t| < 3), but the difference between rotors is well fixed
    (Wald test on the effect's four parameters): pinned down.  The truth: d = (0.3, -0.3, 0.3, -0.3) and a
    body force (0.3, 0.3, 0.2)."""
    rng = np.random.default_rng(2)
    n = 4000
    common = rng.standard_normal(n)
    diff = rng.standard_normal((n, 4))
    diff -= diff.mean(axis=1, keepdims=True)  # the rotors' differences (roll, pitch, yaw) sum to zero
    U = common[:, None] + 0.2 * diff
    F = common + 0.002 * rng.standard_normal(n)  # the body force, nearly the rotors' common mode
    d = np.array([0.3, -0.3, 0.3, -0.3])
    e = ["body_force_bias", "motor_imbalance"]
    # the force (0.3, 0.3, 0.2): its x and y columns are its own, its z one is the rotors' common mode
    X = np.column_stack([rng.standard_normal((n, 2)), F, U])
    y = X @ np.r_[0.3, 0.3, 0.2, d] + 0.5 * rng.standard_normal(n)
    G, h, s, cnt = _blocks(X, y)
    stats = BlockStats(G, h, s, cnt, Columns.of(e))
    from qr.identification.bootstrap import bootstrap
    from qr.identification.normal_equations import fit
    sl = stats.cols.slices["motor_imbalance"]
    t = np.abs(fit(stats, e)[sl]) / bootstrap(stats, e, 100, 0).std(axis=0)[sl]
    assert t.max() < 3  # one by one, no d_i is clearly nonzero ...
    assert pinned_down(stats, e, SelectionConfig(seed=0)) is None  # ... jointly, the imbalance is


def test_the_compiled_bounded_solver_finds_the_bvls_minimiser():
    """box_qp (the selection's bounded solve, a compiled active-set loop) against scipy's BVLS on random
    scaled problems with finite, infinite and neutral (0) bounds: feasible, and no worse a quadratic
    than BVLS's; batched = one by one; where the unconstrained minimum is inside, it is returned."""
    from scipy.linalg import cho_factor, solve_triangular
    from scipy.optimize import lsq_linear

    from qr.identification.box_qp import box_qp, box_qp_many

    rng = np.random.default_rng(3)
    for _ in range(300):
        p = int(rng.integers(1, 13))
        A = rng.normal(size=(p + int(rng.integers(0, 20)), p)) * np.exp(2 * rng.normal(size=p))
        G = A.T @ A + 1e-6 * np.eye(p)
        d = np.sqrt(np.diag(G))
        G, h = G / np.outer(d, d), 3 * rng.normal(size=p) / d
        lb = np.where(rng.random(p) < 0.3, -np.inf, -rng.random(p))
        ub = np.where(rng.random(p) < 0.3, np.inf, rng.random(p))
        lb[rng.random(p) < 0.2] = 0.0
        x = box_qp(G, h, lb, ub)
        L = np.tril(cho_factor(G, lower=True)[0])
        ref = lsq_linear(L.T, solve_triangular(L, h, lower=True), bounds=(lb, ub), method="bvls", tol=1e-14).x
        f = lambda z: 0.5 * z @ G @ z - h @ z  # noqa: E731
        assert np.all(x >= lb) and np.all(x <= ub)
        assert f(x) <= f(ref) + 1e-9 * max(1.0, abs(f(ref)))
        assert np.allclose(box_qp_many(G[None], h[None], lb, ub, np.zeros((1, p)))[0], x, atol=1e-9)
    G, h = np.array([[2.0, 0.5], [0.5, 1.0]]), np.array([1.0, -0.5])
    assert np.allclose(box_qp(G, h, [-10, -10], [10, 10]), np.linalg.solve(G, h))
    # by hand: x2 held at its bound 0, then x1 = h1 / G11
    assert np.allclose(box_qp(G, h, [-10, 0], [10, 10]), [0.5, 0.0])


def test_the_batched_solve_is_the_single_solve_with_its_floor_and_bounds():
    """``solve_many`` (compiled Cholesky, the eigenvalue floor as a shifted factorisation) gives, system
    by system, what ``solve`` gives (numpy's eigh and LU): well-posed, rank-deficient (a column repeated:
    held at the floor) and bound-limited systems in one stack."""
    from qr.identification.normal_equations import solve, solve_many

    rng = np.random.default_rng(11)
    p, Gs, hs = 5, [], []
    for k in range(40):
        A = rng.normal(size=(30, p)) * np.exp(rng.normal(size=p))
        if k % 4 == 1:
            A[:, 3] = A[:, 1]  # singular: a direction with no information
        Gs.append(A.T @ A)
        hs.append(A.T @ rng.normal(size=30) * (8.0 if k % 4 == 2 else 1.0))  # some far outside the bounds
    G, h = np.array(Gs), np.array(hs)
    lb, ub = -np.ones(p), np.ones(p)
    for bounds in ((None, None), (lb, ub)):
        many = solve_many(G, h, *bounds)
        one = np.array([solve(G[k], h[k], 1e-9, *bounds) for k in range(len(G))])
        assert np.allclose(many, one, rtol=1e-7, atol=1e-9)
    assert np.all(np.abs(many) <= 1 + 1e-12) and np.any(np.isclose(np.abs(many), 1.0))  # bounds bite somewhere


def test_per_row_normal_equations_sum_to_any_set_of_rows():
    """``accumulate`` keeps each of the six rows' statistics apart; a set of rows (force, torque, all) is
    their sum, equal to the weighted normal equations of those rows alone, written out directly."""
    from qr.identification.normal_equations import accumulate, row_sums

    rng = np.random.default_rng(5)
    n, p, blocks = 300, 3, np.repeat([0, 1, 2], 100)
    X, y, w = rng.standard_normal((n, 6, p)), rng.standard_normal((n, 6)), rng.uniform(0.5, 2.0, (n, 6))
    y[117, 4] = np.nan  # a sample (of block 1) missing in one row counts in none
    G6, h6, s6, cnt = accumulate(X, y, w, blocks, 3)
    for rows in (None, (0, 1, 2), (3, 4, 5), (3, 4)):
        r = list(range(6)) if rows is None else list(rows)
        keep = np.isfinite(y).all(axis=1) & (blocks == 1)
        Xr, yr, wr = X[keep][:, r], y[keep][:, r], w[keep][:, r]
        np.testing.assert_allclose(row_sums(G6, rows)[1], np.einsum("nrp,nr,nrq->pq", Xr, wr, Xr), rtol=1e-12)
        np.testing.assert_allclose(row_sums(h6, rows)[1], np.einsum("nrp,nr,nr->p", Xr, wr, yr), rtol=1e-12)
        assert row_sums(s6, rows)[1] == pytest.approx(float(np.sum(wr * yr**2)), rel=1e-12)
    assert cnt.tolist() == [600, 594, 600]  # sample-axis count: six per complete sample


def test_rotor_drag_and_its_moment_named_together_share_one_k():
    """The spec: rotor_drag and rotor_drag_moment are one rotor drag's force and moment; named together they
    share one k.  Force rows y_f = 2 x_f, moment rows y_m = 2 x_m + a yaw torque 0.5 x3 (a third effect):
    fitted together, the force and the moment columns carry one k, the least-squares slope of both rows at
    once (by hand: (x_fᵀy_f + x_mᵀy_m) / (x_fᵀx_f + x_mᵀx_m), the third column orthogonal); the bootstrap,
    the cross-validation and the variance inflation see one parameter; a force alone (the moment absent) is
    not forced onto the moment, since each alone keeps its own."""
    from qr.identification.bootstrap import bootstrap
    from qr.identification.normal_equations import CrossValidator, fit, inflation, tie_map

    rng = np.random.default_rng(3)
    n = 6000
    xf, xm, x3 = rng.standard_normal(n), rng.standard_normal(n), rng.standard_normal(n)
    # the force and the moment act on different rows: stacked, each column is zero where the other acts
    X = np.zeros((2 * n, 3))
    X[:n, 0], X[n:, 1], X[n:, 2] = xf, xm, x3
    y = np.concatenate([2.0 * xf, 2.1 * xm + 0.5 * x3]) + 0.1 * rng.standard_normal(2 * n)
    e = ["rotor_drag", "rotor_drag_moment", "yaw_torque_gain"]
    st = BlockStats(*_blocks(X, y), Columns.of(e))
    T = tie_map(e)
    assert T.tolist() == [[1, 0], [1, 0], [0, 1]] and tie_map(["rotor_drag", "yaw_torque_gain"]) is None
    k_hand = (X[:, 0] @ y + X[:, 1] @ y - (X[:, 0] + X[:, 1]) @ X[:, 2] * 0.5) / (xf @ xf + xm @ xm)
    th = fit(st, e)
    assert th[0] == th[1] == pytest.approx(k_hand, rel=1e-3) and th[2] == pytest.approx(0.5, abs=0.01)
    assert 2.0 < th[0] < 2.1  # between the rows' own slopes
    reps = bootstrap(st, e, 50, 0)
    assert np.array_equal(reps[:, 0], reps[:, 1])
    assert inflation(st, e)[0] == inflation(st, e)[1] == pytest.approx(1.0, abs=0.05)
    cv = CrossValidator(st, 5)
    assert cv.loss(e) < cv.loss(["rotor_drag", "yaw_torque_gain"])
    assert fit(st, ["rotor_drag_moment"])[0] == pytest.approx(2.1, abs=0.01)  # alone: its own k
