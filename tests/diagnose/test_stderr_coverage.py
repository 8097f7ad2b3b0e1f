"""Standard errors mean what they say: the true parameter lies within 2 s.e. of the estimate in at
least 85 % of cases, per mechanism family (20 seeded 60 s flights each; benchmarks/stderr_coverage.py
prints the same table).  The estimator is under test, not the selection: each flight is diagnosed with
its hidden effect as the only candidate; a flight on which it is too small to be named has no s.e. and
is left out (at most a quarter of them)."""

import numpy as np
import pytest

from qr.sim.scenarios import FAMILIES, coverage_cases, z_scores


@pytest.mark.parametrize("family", list(FAMILIES))
def test_two_standard_errors_cover_the_truth(family, tmp_path):
    z = np.array([x for case in coverage_cases(family, 20) for x in z_scores(case, tmp_path)])
    named = np.isfinite(z)
    assert named.mean() >= 0.75, z
    assert np.mean(np.abs(z[named]) <= 2) >= 0.85, np.round(z, 2)
