"""The on-board gyro as a second attitude-filter measurement, ``z = ω_b + b + ν``
(:func:`qr.estimation.attitude_eskf.gyro_H`): a constant bias from a first mocap-only pass, the noise from
the gyro's own second difference.  docs/filter.md.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..flight import GYRO as COLUMNS

MIN_SAMPLES = 20


def samples(flight: pd.DataFrame) -> np.ndarray | None:
    """The gyro columns (N, 3), or None when the log has (almost) none."""
    if not all(c in flight.columns for c in COLUMNS):
        return None
    g = flight[COLUMNS].to_numpy(dtype=float)
    return g if np.all(np.isfinite(g), axis=1).sum() >= MIN_SAMPLES else None


def noise_variance(g: np.ndarray) -> float:
    """Per-axis white-noise variance from the second difference (MAD, robust to manoeuvres), averaged."""
    ok = np.all(np.isfinite(g), axis=1)
    d2 = np.diff(g[ok], 2, axis=0)
    mad = 1.4826 * np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
    return float(np.mean(mad**2) / 6)


def bias(g: np.ndarray, w_body: np.ndarray) -> np.ndarray:
    """Constant bias: median of the gyro minus the mocap-only body-rate estimate."""
    ok = np.all(np.isfinite(g), axis=1) & np.all(np.isfinite(w_body), axis=1)
    return np.median(g[ok] - w_body[ok], axis=0)
