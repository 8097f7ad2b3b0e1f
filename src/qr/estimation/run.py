"""The filter stage's computation on one canonical flight (``qr filter``, the workflow's filter jobs): the state
table, the NIS report with the tuning record (a tuning filter's noise values, tuned on the flight's longest
airborne segment, frozen for the whole flight), and every segment's cross-fit estimates the diagnoses read."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import pandas as pd

from .nis import NisReport


@dataclass(frozen=True)
class FilterRun:
    """One flight filtered."""

    states: pd.DataFrame  # the state table (qr.states)
    report: NisReport  # written to ``.nis.json``: filter, NIS, noise, the tuning record, flight, config
    seconds: float  # wall-clock time of the tuning and the filters (the MLflow run's metric; in no file)
    crossfit: pd.DataFrame | None  # every airborne segment's estimates (:func:`.crossfit.segment_estimates`)


def run(flight: pd.DataFrame, vehicle, cfg: dict, name: str, source: str, progress: bool = False,
        crossfit: bool = False) -> FilterRun:
    """Filter ``flight`` with ``cfg`` (the config group ``filter`` less its paths)."""
    from .crossfit import airborne_tuning, fixed_settings, segment_estimates
    from .pipeline import TUNED_NIS_NOTE, estimate

    start = time.perf_counter()
    tuned = airborne_tuning(flight, vehicle, cfg, progress)  # (values, window) or None
    states, report = estimate(flight, vehicle, fixed_settings(cfg, tuned and tuned[0]), progress=progress,
                              source=source)
    seconds = time.perf_counter() - start
    # the whole flight filtered with the values tuned on its airborne rows
    record = dict(tuning=tuned[0], tuned_on_s=tuned[1], nis_note=TUNED_NIS_NOTE) if tuned else {}
    report = replace(report, **record, flight=name, config=cfg)
    table = segment_estimates(flight, vehicle, cfg, report) if crossfit else None
    return FilterRun(states, report, seconds, table)


def metrics(report: NisReport, seconds: float | None) -> dict:
    """A filter run's MLflow metrics from its report: NIS per filter, noise values (``seconds``: None for a
    run logged later, whose report file must stay reproducible)."""
    m = {"inconsistent_filters": len(report.inconsistent)}
    if seconds is not None:
        m["seconds"] = seconds
    for name, st in report.nis.channels():
        if st.mean is not None:
            m[f"nis.{name}.mean"] = st.mean
            m[f"nis.{name}.consistent"] = float(st.consistent)
            m[f"nis.{name}.outside_sample_band"] = st.outside_sample_band
    for f, noise in report.noise.items():
        for k, v in noise.items():
            m[f"noise.{f}.{k}"] = v if not isinstance(v, list) else max(v)
    return m


def nis_table(reports: dict[str, NisReport]) -> pd.DataFrame:
    """One row per flight (``reports``: name -> NIS report): each filter's mean NIS, its band and verdict."""
    rows = []
    for name, rep in reports.items():
        row = {"flight": name, "filter": rep.filter, "samples": rep.samples}
        for f, st in (("position", rep.nis.position), ("attitude", rep.nis.attitude), ("rotors", rep.nis.motor["all"])):
            row[f"{f}_nis"] = st.mean
            row[f"{f}_band"] = "–".join(f"{b:.3g}" for b in st.band) if st.band else ""
            row[f"{f}_ok"] = st.consistent
            row[f"{f}_outside"] = st.outside_sample_band  # expected: 1 - confidence
        row["flagged"] = ", ".join(rep.inconsistent) or "-"
        rows.append(row)
    return pd.DataFrame(rows)
