"""The one intake of the commands that read canonical flights: flights + vehicle + settings -> the flights
checked and every used segment's estimates (:class:`Intake`).

Each fact once:

- the convention checks (:mod:`qr.conventions`, :func:`check_conventions`): a log in another frame, order or
  unit is refused in one line naming the setting that skips the check;
- the piece cutting (:func:`qr.segments.flight_segments`): airborne, gap-free segments, those shorter than the
  command's minimum length (:func:`qr.segments.min_segment_s`, the one rule) kept but not used;
- the filter stage's tuning record (its ``.nis.json``, :func:`read_reports`) and cross-fit file: a segment's
  estimates read where the filter stage made them with the same settings, else filtered by the same recipe
  (:func:`qr.estimation.crossfit.prepare_flight`, the longest segment first: a tuning filter is tuned there
  once per flight).  The same numbers either way.

Several commands run in one process on the same flights (a workflow fold: its diagnosis, its rollouts, its
residual) share a :class:`Memo`: each flight is read and convention-checked once, each segment's estimates
read or filtered once.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import pandas as pd

from .estimation.nis import NisReport
from .segments import FlightSegments, flight_segments

if TYPE_CHECKING:  # (the filters imported when a segment is estimated, after the inputs are checked)
    from .conventions import FlightChecks
    from .estimation.crossfit import SegmentEstimate


def shown(paths) -> list[str]:
    """Each file as messages and keys name it: its name, its path where two names clash."""
    short = [Path(str(f)).name for f in paths]
    return [str(f) if short.count(n) > 1 else n for f, n in zip(paths, short)]


@dataclass(frozen=True)
class Flights:
    """The flights as taken: names as the user gave them, rows, segments, convention checks."""

    names: list[str]
    measured: list[pd.DataFrame]
    split: list[FlightSegments]
    conventions: list[FlightChecks]  # per flight: what each check measured


@dataclass(frozen=True)
class IntakeSettings:
    """How a command takes its flights."""

    min_segment_s: float  # a shorter airborne, gap-free segment is not used
    filter: dict  # the filter settings the estimates are made with (resolved)
    skip_checks: tuple[str, ...] = ()  # convention checks turned off
    how_to_skip: str = "diagnose.skip_checks=[{name}] at the end of the command"  # said in a refusal
    halves: bool = True  # the cross-fitting halves too (a diagnosis); False: the full estimate alone (a rollout)


@dataclass(frozen=True)
class Intake:
    """The flights checked and cut, and every used segment's estimates (flights in order, each one's
    segments in time order)."""

    flights: Flights
    estimates: tuple[SegmentEstimate, ...]


class Memo:
    """What the intake already took in this process, for the next command on the same flights: the rows of each
    flight file, each flight's convention checks (against a vehicle of the same physical properties: the checks
    read no effect, so the nominal, extended and hybrid vehicles of one diagnosis share them), each flight's
    segment estimates.  Everything is keyed by what it depends on; what a command may change is handed out as
    a copy."""

    def __init__(self):
        self._rows: dict[str, pd.DataFrame] = {}
        self._checks: dict[tuple, FlightChecks] = {}
        self._made: dict[tuple, list] = {}

    def rows(self, path, read: Callable) -> pd.DataFrame:
        key = str(path)
        if key not in self._rows:
            self._rows[key] = read(path)
        return self._rows[key].copy()

    def checks(self, path, vehicle, skip, check: Callable[[], FlightChecks]) -> FlightChecks:
        key = (str(path), tuple(skip), _physical(vehicle))
        if key not in self._checks:
            self._checks[key] = check()
        return self._checks[key]

    def estimates(self, flight, stored, segments, vehicle, filter_cfg: dict, report: NisReport | None,
                  halves: bool, made: Callable) -> list[tuple]:
        """``(segment, states, halves, source)`` as ``made()`` (:func:`qr.estimation.crossfit.
        estimate_segments` on ``segments``) yields them, each segment estimated once (a cross-fitted one serves
        a request without halves); ``stored``: the cross-fit file they are read from where it has them (read
        again for other segments or settings: ~10 ms)."""
        k = (str(flight), str(stored), tuple(s.window for s in segments),
             json.dumps([filter_cfg, report and report.to_json(), float(vehicle.hover_speed)], sort_keys=True,
                        default=str))
        got = self._made.get((*k, True)) or self._made.get((*k, halves))
        if got is None:
            got = self._made[(*k, halves)] = [(seg.window, st, pair, source) for seg, st, pair, source in made()]
        seg = {s.window: s for s in segments}
        return [(seg[w], st.copy(), tuple(t.copy() for t in pair) if halves else None, source)
                for w, st, pair, source in got]


def _physical(vehicle) -> str:
    """The vehicle's properties the convention checks may read (not its effects or learned parts)."""
    return json.dumps({k: v for k, v in vehicle.raw.items() if k not in ("effects", "torque_remainder", "residual")},
                      sort_keys=True, default=str)


def read_reports(nis_files: Sequence) -> list[NisReport]:
    """The filter stage's reports (``.nis.json``: its tuning record), one per flight."""
    return [NisReport.from_json(json.loads(Path(p).read_text())) for p in nis_files]


def read_flights(paths: Sequence, memo: Memo | None = None) -> list[pd.DataFrame]:
    """The canonical flights, each validated (:func:`qr.flight.read_flight`; its unit check, which needs the
    vehicle's ground rows, comes with the cutting)."""
    from .flight import read_flight

    return [memo.rows(f, read_flight) if memo else read_flight(f) for f in paths]


def check_conventions(df: pd.DataFrame, vehicle, path, skip=(), how_to_skip: str = IntakeSettings.how_to_skip,
                      vehicle_file=None) -> FlightChecks:
    """What each convention check measured; a failed check refuses the log (:func:`qr.conventions.require`)."""
    from . import conventions

    return conventions.FlightChecks(str(path), tuple(conventions.require(df, vehicle, path, skip, how_to_skip,
                                                                         vehicle_file)))


def take(names: list[str], measured: list[pd.DataFrame], vehicle, settings: IntakeSettings, vehicle_file=None,
         reports: list | None = None, stored: list | None = None, say: Callable[[str], None] = lambda msg: None,
         require: Callable[[str, FlightSegments], None] | None = None,
         on_checked: Callable[[], None] | None = None, memo: Memo | None = None) -> Intake:
    """The flights ``names`` (their rows ``measured``) checked, cut and estimated.

    Per flight, in order: cut (a log that never flew is refused), the convention checks, then ``require(name,
    segments)`` (a command's own refusal, e.g. too short to hold out a test part).  ``on_checked()``: called once
    every flight passed, before the estimates (the filters) start.  ``reports`` / ``stored``: per flight, the
    filter stage's report and cross-fit file (``vehicle_file``: the file ``vehicle`` was read from, named in
    a fix; ``memo``: what an earlier command of this process took)."""
    split, checks = [], []
    for f, m in zip(names, measured):
        fs = flight_segments(m, vehicle, settings.min_segment_s, f)
        check = lambda: check_conventions(m, vehicle, f, settings.skip_checks, settings.how_to_skip,  # noqa: E731
                                          vehicle_file)
        checks.append(memo.checks(f, vehicle, settings.skip_checks, check) if memo else check())
        if require is not None:
            require(f, fs)
        split.append(fs)
    named = shown(names)
    for f, fs in zip(named, split):
        _say_segments(say, f, fs)
    if on_checked is not None:
        on_checked()
    flights = Flights(list(names), list(measured), split, checks)
    return Intake(flights, _estimates([fs.used for fs in split], named, vehicle,
                                      settings.filter, reports, stored, say, settings.halves, names, memo))


def _estimates(segments: list, named: list[str], vehicle, filter_cfg: dict, reports: list | None,
               stored: list | None, say, halves: bool, names: list[str], memo: Memo | None) \
        -> tuple[SegmentEstimate, ...]:
    """Every flight's used ``segments`` estimated (:func:`qr.estimation.crossfit.estimate_segments`), read from
    the flight's cross-fit file where it was made with the same settings."""
    from .estimation.crossfit import Estimates, SegmentEstimate, estimate_segments

    out = []
    for i, used in enumerate(segments):
        report = reports[i] if reports else None
        file = Estimates(stored[i], filter_cfg, report.tuning, vehicle) if stored and stored[i] and report else None
        made = lambda: estimate_segments(used, vehicle, filter_cfg, report, halves, file)  # noqa: E731
        got = memo.estimates(names[i], stored[i] if file else None, used, vehicle, filter_cfg, report, halves,
                             made) if memo else made()
        for seg, st, pair, source in got:
            say(f"estimates of {named[i]} {seg.window[0]:.2f}-{seg.window[1]:.2f} s ({len(seg.rows)} samples): "
                f"{source}")
            for table in (st, *(pair or ())):
                table.attrs["flight"] = i
            out.append(SegmentEstimate(i, seg.window, seg.rows, st, pair))
    return tuple(sorted(out, key=lambda e: (e.flight, e.window[0])))


def _say_segments(say, name: str, fs: FlightSegments) -> None:
    if fs.ground_s > 0:
        spans = ", ".join(f"{a:.2f}-{b:.2f} s" for a, b in fs.airborne)
        say(f"{name}: airborne {spans}; {fs.ground_s:.1f} s on the ground left out")
    for g0, g1 in fs.gaps:
        say(f"{name}: no samples from {g0:.2f} to {g1:.2f} s: the parts before and after are separate segments")
    for seg in fs.segments:
        if not seg.used:
            say(f"{name}: segment {seg.window[0]:.2f}-{seg.window[1]:.2f} s not used: {seg.note}")
