"""The evaluate protocol's pieces of flights with their start states: how ``qr evaluate`` and ``qr learn
residual`` take their flights (:func:`rollout_pieces`, through the one intake :func:`qr.intake.take`)."""

from __future__ import annotations

import pandas as pd

from .errors import QrInputError
from .intake import IntakeSettings, Memo, take
from .rollout import EvaluateConfig, pieces
from .segments import ROLLOUT_SPAN_S, FlightSegments, min_segment_s


def intake_settings(ecfg: EvaluateConfig, filter_cfg: dict) -> IntakeSettings:
    """A segment is used if it holds ``trim_s`` at each end and a rollout's span (:func:`qr.segments.min_segment_s`);
    the full estimate alone (a rollout's start states need no cross-fitting)."""
    return IntakeSettings(min_segment_s(ecfg.trim_s, ROLLOUT_SPAN_S), filter_cfg, tuple(ecfg.skip_checks),
                          "evaluate.skip_checks=[{name}] at the end of the command", halves=False)


def _require(path, fs: FlightSegments) -> None:
    if not fs.used:
        raise QrInputError(path, "no airborne, gap-free segment is long enough to evaluate",
                           "give a longer flight, or a smaller evaluate.trim_s")


def rollout_pieces(names: list[str], measured: list[pd.DataFrame], vehicle, ecfg: EvaluateConfig, filter_cfg: dict,
                   reports: list | None = None, stored: list | None = None, say=lambda msg: None,
                   vehicle_file=None, memo: Memo | None = None) -> list[list]:
    """Per flight (``names``, their rows ``measured``), the protocol's pieces ``(states, measured, keep)`` of each
    used segment (:func:`qr.rollout.pieces`).  Every flight is checked (conventions, a usable segment) before
    any is filtered; ``reports`` / ``stored``: per flight, the filter stage's report and cross-fit file; ``memo``:
    what an earlier command of this process took (:class:`qr.intake.Memo`)."""
    taken = take(names, measured, vehicle, intake_settings(ecfg, filter_cfg), vehicle_file, reports, stored, say,
                 _require, memo=memo)
    out: list[list] = [[] for _ in names]
    for e in taken.estimates:
        out[e.flight].append(pieces(e.states, e.rows, ecfg.trim_s))
    return out
