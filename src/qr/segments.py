"""A flight's usable pieces: its airborne part (``qr.airborne``), cut at long time gaps.

A gap in the time stamps far longer than the sample period (a logger or radio
outage) is no dropout the filters should bridge: their prediction across it,
the smoother's interpolation, a difference, a replay window or a train/test
boundary that spans it would all treat unseen motion as seen.  Each segment is
filtered and diagnosed on its own.  A gap is a step longer than
``max(GAP_STEPS x the median step, GAP_MIN_S)``: ten missed samples, and at least
0.1 s, several time constants of any filter used on a quadrotor.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .airborne import check_airborne

GAP_STEPS = 10
GAP_MIN_S = 0.1
ROLLOUT_SPAN_S = 0.5  # a rollout's segment: half a second of starts between its trims
STORED_SPAN_S = 1.0  # the filter stage's cross-fit file (and the learning data set read from it)


def min_segment_s(trim_s: float, span_s: float) -> float:
    """The one minimum length of a used segment: ``trim_s`` dropped at each end (the filters' start-up and end)
    and ``span_s`` left between for the reader: a diagnosis one cross-validation block (``diagnose.block_s``), a
    rollout :data:`ROLLOUT_SPAN_S` of starts, the filter stage (no trim, its readers' settings unknown: one
    that uses a shorter segment filters it itself) :data:`STORED_SPAN_S`."""
    return 2 * trim_s + span_s


def gap_threshold(t: np.ndarray) -> float:
    return max(GAP_STEPS * float(np.median(np.diff(t))), GAP_MIN_S) if len(t) > 1 else GAP_MIN_S


def time_gaps(t: np.ndarray, threshold: float | None = None) -> list[tuple[float, float]]:
    """``[(last stamp before, first stamp after), ...]`` of the gaps longer than ``threshold``."""
    threshold = gap_threshold(t) if threshold is None else threshold
    i = np.flatnonzero(np.diff(t) > threshold)
    return [(float(t[k]), float(t[k + 1])) for k in i]


@dataclass
class Segment:
    window: tuple[float, float]  # first and last stamp, the log's own time
    rows: pd.DataFrame  # the flight's rows, index reset
    used: bool = True
    note: str = ""


@dataclass
class FlightSegments:
    """What of one flight is used: its airborne windows and the gap-free segments inside them."""

    airborne: list[tuple[float, float]]
    ground_s: float  # time outside the airborne windows (s): on the ground, dropped
    gaps: list[tuple[float, float]]  # time gaps inside the airborne windows
    segments: list[Segment] = field(default_factory=list)

    @property
    def used(self) -> list[Segment]:
        return [s for s in self.segments if s.used]


def flight_segments(flight: pd.DataFrame, vehicle, min_s: float, path=None) -> FlightSegments:
    """Split a canonical flight into airborne, gap-free segments; those shorter than ``min_s`` are not used.

    Refuses (``QrInputError``) a log whose vehicle never flew.
    """
    t = flight["t"].to_numpy(dtype=float)
    windows = check_airborne(flight, vehicle, path)
    threshold = gap_threshold(t)
    airborne_s = sum(b - a for a, b in windows)
    out = FlightSegments(windows, float(t[-1] - t[0] - airborne_s), [])
    for a, b in windows:
        inside = (t >= a) & (t <= b)
        rows = flight[inside].reset_index(drop=True)
        tw = t[inside]
        gaps = time_gaps(tw, threshold)
        out.gaps += gaps
        cuts = np.concatenate([[0], np.flatnonzero(np.diff(tw) > threshold) + 1, [len(tw)]])
        for i, j in zip(cuts[:-1], cuts[1:]):
            seg = Segment((float(tw[i]), float(tw[j - 1])), rows.iloc[i:j].reset_index(drop=True))
            length = seg.window[1] - seg.window[0]
            if length < min_s:
                seg.used, seg.note = False, f"lasts {length:.2f} s, shorter than the {min_s:.2f} s a segment needs"
            out.segments.append(seg)
    return out
