"""The flights of a diagnosis as read: their rows, their airborne gap-free segments, their convention checks.

Checked before any estimate is made: a log in another frame or unit (:mod:`qr.conventions`), one that
never flew, or one too short to hold out a test part is refused in one line with its fix.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from .. import conventions
from ..errors import QrInputError
from ..segments import FlightSegments, flight_segments
from .settings import DiagnoseConfig


@dataclass(frozen=True)
class Flights:
    """The flights of one diagnosis: names as the user gave them, rows, segments, convention checks."""

    names: list[str]
    measured: list[pd.DataFrame]
    split: list[FlightSegments]
    conventions: list[dict]  # per flight: {"flight", "checks": what each check measured}


def check_flights(names: list[str], measured: list[pd.DataFrame], vehicle, cfg: DiagnoseConfig,
                  say=lambda msg: None, vehicle_file=None) -> Flights:
    """The flights, each checked (conventions, airborne segments, length) and its left-out rows said
    (``vehicle_file``: the file ``vehicle`` was read from, named in a fix)."""
    # the training part of a lone flight must hold a block per cross-validation fold
    blocks = cfg.selection.folds if len(names) == 1 else 1
    need = (blocks * cfg.block_s + cfg.gap_s / 2) / cfg.train_fraction
    split, checks = [], []
    for f, m in zip(names, measured):
        fs = flight_segments(m, vehicle, 2 * cfg.trim_s + cfg.block_s, f)
        checks.append({"flight": str(f), "checks": [r.as_dict() for r in conventions.require(
            m, vehicle, f, cfg.skip_checks, "diagnose.skip_checks=[{name}] at the end of the command",
            vehicle_file)]})
        _check_length(f, fs, need, cfg, blocks)
        split.append(fs)
    for f, fs in zip(names, split):
        _say_segments(say, Path(f).name, fs)
    return Flights(list(names), list(measured), split, checks)


def _check_length(path, fs: FlightSegments, need: float, cfg: DiagnoseConfig, blocks: int) -> None:
    """Refuse a flight whose used segments, less ``trim_s`` at each end, cannot hold ``need`` seconds."""
    longest = max(s.window[1] - s.window[0] for s in fs.segments)
    n = len(fs.used)
    lasts = sum(s.window[1] - s.window[0] for s in fs.used)
    fits = ((lasts - 2 * cfg.trim_s * n) * cfg.train_fraction - cfg.gap_s / 2) / blocks  # the block that fits
    shorter = (f", or shorter cross-validation blocks: add diagnose.block_s={math.floor(10 * fits) / 10:g} "
               "at the end of the command" if fits >= 0.5 else "")
    fix = f"give a longer flight (30 s or more) or several flights{shorter}"
    if not fs.used:
        raise QrInputError(path, f"no airborne stretch without a time gap lasts {2 * cfg.trim_s + cfg.block_s:.1f} s "
                                 f"(2 trim_s + block_s; the longest: {longest:.1f} s)", fix)
    if lasts - 2 * cfg.trim_s * n < need:
        where = "airborne" if not fs.gaps else f"airborne in {n} segment{'s' if n > 1 else ''} between time gaps"
        raise QrInputError(path, f"flight lasts {lasts:.1f} s {where}, too short to hold out a test part "
                                 f"(needs {need + 2 * cfg.trim_s * n:.1f} s)", fix)


def _say_segments(say, name: str, fs: FlightSegments) -> None:
    if fs.ground_s > 0:
        spans = ", ".join(f"{a:.2f}-{b:.2f} s" for a, b in fs.airborne)
        say(f"{name}: airborne {spans}; {fs.ground_s:.1f} s on the ground left out")
    for g0, g1 in fs.gaps:
        say(f"{name}: no samples from {g0:.2f} to {g1:.2f} s: the parts before and after are separate segments")
    for seg in fs.segments:
        if not seg.used:
            say(f"{name}: segment {seg.window[0]:.2f}-{seg.window[1]:.2f} s not used: {seg.note}")
