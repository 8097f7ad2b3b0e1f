"""The speed work under the filters: the smoother step's linear algebra, the threads and the tuning-only path.

Each is checked against an independent computation (numpy's inverse, one thread, the filter's own report),
so a faster kernel cannot drift from what it replaces.
"""

from __future__ import annotations

import numba
import numpy as np
import pandas as pd
import pytest

from qr.config import compose, to_dict
from qr.estimation import estimate, fast, tuned_noise

from estimation_data import model_flight


def _spd(rng, n, cond=1e3):
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return (Q * np.geomspace(1.0, 1.0 / cond, n)) @ Q.T


@pytest.mark.parametrize("n", [3, 4, 12])
def test_the_rts_step_equals_the_textbook_formula(n):
    rng = np.random.default_rng(n)
    Pk, Pnext = _spd(rng, n), _spd(rng, n)
    Phi = np.eye(n) + 0.1 * rng.standard_normal((n, n))
    pP = Phi @ Pk @ Phi.T + _spd(rng, n, 10.0) * 0.01
    dd = np.outer(*(2 * [rng.uniform(0.5, 2.0, n)]))
    K, out, scratch = np.empty((n, n)), np.empty((n, n)), np.empty((4, n, n))
    fast._rts_step(Pk, Phi @ Pk, pP, Pnext, dd, K, scratch, out)
    C = Pk @ Phi.T @ np.linalg.inv(pP)  # RTS gain and covariance, as the numpy reference writes them
    np.testing.assert_allclose(K, C, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(out, (Pk + C @ (Pnext * dd - pP) @ C.T) / dd, rtol=1e-9, atol=1e-12)
    assert np.array_equal(out, out.T)


def test_a_predicted_covariance_that_is_not_positive_definite_takes_the_pivoting_inverse():
    rng = np.random.default_rng(7)
    n = 4
    Pk = _spd(rng, n)
    pP = np.diag([1.0, 2.0, -1e-3, 3.0])  # indefinite: no Cholesky factor
    L, X = np.empty((n, n)), np.empty((n, n))
    assert not fast._cholesky_solve(pP, Pk, L, X)
    K, out, scratch = np.empty((n, n)), np.empty((n, n)), np.empty((4, n, n))
    fast._rts_step(Pk, Pk, pP, Pk, np.ones((n, n)), K, scratch, out)
    np.testing.assert_allclose(K, Pk @ np.linalg.inv(pP), rtol=1e-12)


@pytest.fixture(scope="module")
def flight():
    return model_flight(seed=3, duration=12.0, rate=100.0)[0]


def test_the_three_filters_give_the_same_digits_on_one_thread_and_on_two(flight):
    """The filters of a flight (and a flight's cross-fitting parts) run side by side on numba's threads;
    no number may depend on it."""
    from qr.estimation.crossfit import prepare_flight

    cfg = to_dict(compose(["filter=auto"]))["filter"]
    before = numba.get_num_threads()
    runs = []
    try:
        for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(threads)
            tuned = tuned_noise(flight, None, cfg)
            st, (even, odd) = prepare_flight(flight, None, cfg, tuned)
            runs.append((st, even, odd, tuned))
    finally:
        numba.set_num_threads(before)
    for a, b in zip(runs[0][:3], runs[1][:3]):
        pd.testing.assert_frame_equal(a, b, check_exact=True)
    assert runs[0][3] == runs[1][3]


def test_tuning_alone_gives_the_values_the_tuned_filter_reports(flight):
    cfg = to_dict(compose(["filter=auto"]))["filter"]
    _, report = estimate(flight, None, cfg)
    assert tuned_noise(flight, None, cfg) == report.tuning
    assert tuned_noise(flight, None, to_dict(compose([]))["filter"]) is None  # the thesis filters do not tune


def test_blas_keeps_one_thread_inside_a_diagnosis_and_its_own_count_after():
    """qr's threads use the cores; numpy's BLAS, which would start its own, is held to one meanwhile."""
    from threadpoolctl import threadpool_info

    from qr.parallel import blas_one_thread

    def blas_threads():
        return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]

    np.ones((64, 64)) @ np.ones((64, 64))  # BLAS loaded
    before = blas_threads()
    assert before
    with blas_one_thread():
        assert blas_threads() == [1] * len(before)
    assert blas_threads() == before
