"""The evaluate protocol's pieces of a flight with their start states: the one path by which ``qr evaluate``
and ``qr learn residual`` get their windows (:func:`estimated_pieces`)."""

from __future__ import annotations

import pandas as pd

from .errors import QrInputError
from .rollout import EvaluateConfig, pieces


def estimated_pieces(path, flight: pd.DataFrame, vehicle, ecfg: EvaluateConfig, filter_cfg: dict,
                     report: dict | None = None, stored=None, say=lambda msg: None) -> list:
    """The evaluate protocol's pieces of one flight: ``(states, measured, keep)`` per airborne, gap-free
    segment (:func:`qr.rollout.pieces`), the start states from the filter stage's estimate.

    Split like ``qr diagnose`` splits a flight; each segment filtered with ``filter_cfg`` (the tuned noise
    values of the filter stage's ``report`` frozen, when given) or, with ``stored`` (the filter stage's
    cross-fit file, with ``report``), its estimate read from there where it matches."""
    from .estimation import estimate
    from .estimation.crossfit import Estimates, fixed_settings
    from .segments import flight_segments

    fs = flight_segments(flight, vehicle, 2 * ecfg.trim_s + 0.5, path)
    settings = fixed_settings(filter_cfg, report) if report else filter_cfg
    stored = Estimates(stored, filter_cfg, report, vehicle) if stored is not None and report else None
    out = []
    for seg in fs.used:
        got = stored.get(seg.window[0]) if stored else None
        say(f"estimates of {path} {seg.window[0]:.2f}-{seg.window[1]:.2f} s ({len(seg.rows)} samples): "
            + ("read from the filter stage" if got else "filtering"))
        st = got[0] if got else estimate(seg.rows, vehicle, settings)[0]
        out.append(pieces(st, seg.rows, ecfg.trim_s))
    if not out:
        raise QrInputError(path, "no airborne, gap-free segment is long enough to evaluate",
                           "give a longer flight, or a smaller evaluate.trim_s")
    return out
