"""How a diagnosis takes its flights (:mod:`qr.intake`): its minimum segment length, and its own refusal of a
flight too short to hold out a test part.

Checked before any estimate is made: a log in another frame or unit (:mod:`qr.conventions`), one that
never flew, or one too short to hold out a test part is refused in one line with its fix.
"""

from __future__ import annotations

import math

from ..errors import QrInputError
from ..intake import IntakeSettings
from ..segments import FlightSegments, min_segment_s
from .settings import DiagnoseConfig


def intake_settings(cfg: DiagnoseConfig, filter_cfg: dict) -> IntakeSettings:
    """A segment is used if it holds ``trim_s`` at each end and one cross-validation block
    (:func:`qr.segments.min_segment_s`)."""
    return IntakeSettings(min_segment_s(cfg.trim_s, cfg.block_s), filter_cfg, tuple(cfg.skip_checks),
                          "diagnose.skip_checks=[{name}] at the end of the command")


def length_check(cfg: DiagnoseConfig, flights: int):
    """``require(path, segments)`` of :func:`qr.intake.take`: refuse a flight whose used segments, less
    ``trim_s`` at each end, cannot hold the training part (of a lone flight: a block per cross-validation fold)."""
    blocks = cfg.selection.folds if flights == 1 else 1
    need = (blocks * cfg.block_s + cfg.gap_s / 2) / cfg.train_fraction
    return lambda path, fs: _check_length(path, fs, need, cfg, blocks)


def _check_length(path, fs: FlightSegments, need: float, cfg: DiagnoseConfig, blocks: int) -> None:
    longest = max(s.window[1] - s.window[0] for s in fs.segments)
    n = len(fs.used)
    lasts = sum(s.window[1] - s.window[0] for s in fs.used)
    fits = ((lasts - 2 * cfg.trim_s * n) * cfg.train_fraction - cfg.gap_s / 2) / blocks  # the block that fits
    shorter = (f", or shorter cross-validation blocks: add diagnose.block_s={math.floor(10 * fits) / 10:g} "
               "at the end of the command" if fits >= 0.5 else "")
    fix = f"give a longer flight (30 s or more) or several flights{shorter}"
    if not fs.used:
        raise QrInputError(path, f"no airborne stretch without a time gap lasts "
                                 f"{min_segment_s(cfg.trim_s, cfg.block_s):.1f} s (2 trim_s + block_s; the longest: "
                                 f"{longest:.1f} s)", fix)
    if lasts - 2 * cfg.trim_s * n < need:
        where = "airborne" if not fs.gaps else f"airborne in {n} segment{'s' if n > 1 else ''} between time gaps"
        raise QrInputError(path, f"flight lasts {lasts:.1f} s {where}, too short to hold out a test part "
                                 f"(needs {need + 2 * cfg.trim_s * n:.1f} s)", fix)
