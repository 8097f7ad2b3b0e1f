"""One stream onto another's stamps: what every adapter does with the streams beside the pose."""

from __future__ import annotations

import numpy as np


def onto(t: np.ndarray, stamps: np.ndarray, values) -> np.ndarray:
    """``values`` sampled at ``stamps`` (any order), linearly interpolated at ``t`` (both in the same
    clock and unit); NaN outside the stream's own span (no extrapolation)."""
    stamps = np.asarray(stamps, dtype=float)
    order = np.argsort(stamps, kind="stable")
    return np.interp(t, stamps[order], np.asarray(values, dtype=float)[order], left=np.nan, right=np.nan)
