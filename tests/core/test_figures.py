"""Shared figure helpers (qr.report.figures): flights drawn one after another are never joined."""

import numpy as np


def test_end_to_end_breaks_between_flights_and_across_time_gaps():
    from qr.report.figures import end_to_end

    # flight 0: 10.00-10.04 s with a gap after 10.02; flight 1: 3.00-3.02 s (its own clock)
    t = np.array([10.00, 10.01, 10.02, 10.30, 10.31, 3.00, 3.01, 3.02])
    g = np.array([0, 0, 0, 0, 0, 1, 1, 1])
    y = np.arange(8.0)[:, None] * [1.0, -1.0]
    x, (yy,), spans = end_to_end(t, g, y, spacing=0.5)
    breaks = np.flatnonzero(np.isnan(x))
    assert list(breaks) == [3, 6, 10]  # after the gap, after flight 0, at the end
    assert np.isnan(yy[breaks]).all() and np.array_equal(yy[~np.isnan(x)], y)
    # flight 0 keeps its own time; flight 1 starts 0.5 x the total span (0.31 + 0.02 s) after it ends
    np.testing.assert_allclose(x[:3], [10.00, 10.01, 10.02])
    np.testing.assert_allclose(x[7:10], 10.31 + 0.5 * 0.33 + np.array([0.0, 0.01, 0.02]))
    np.testing.assert_allclose(spans, [(10.00, 10.31), (10.31 + 0.165, 10.31 + 0.165 + 0.02)])
    assert np.all(np.diff(x[~np.isnan(x)]) > 0)  # one time axis, always forward
