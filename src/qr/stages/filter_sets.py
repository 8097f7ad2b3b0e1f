"""The workflow's filter jobs (workflow/rules/filter.smk): a set's flights filtered in batches, one MLflow run
per flight logged from one process, the NIS table of all flights, and the filtered-vs-raw figures."""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

from .. import tracking
from ..config import compose, to_dict
from ..intake import read_reports
from ..shipped import vehicle_file as find_vehicle
from .filter import run_filter, track_filter


def run_batch(flights, vehicle_file, outs, nis_outs, crossfit_outs, names, overrides=()) -> None:
    """The workflow's filter job: several flights of one set in one process (Python, numba's compiled
    kernels and Hydra start once per batch, not once per flight), each as :func:`run_filter` alone
    (``track=False``: their MLflow runs are logged by :func:`track_runs`)."""
    cfg = to_dict(compose(list(overrides)))
    vehicle_file = vehicle_file or find_vehicle(cfg["vehicle"])
    for job in zip(flights, outs, nis_outs, crossfit_outs, names, strict=True):
        flight, out, nis_out, crossfit_out, name = job
        report = run_filter(flight, vehicle_file, out, nis_out, cfg["filter"], name, track=False,
                            crossfit_out=crossfit_out)
        print(f"{name}: filter={report.filter}, NIS-inconsistent: {', '.join(report.inconsistent) or 'none'}",
              file=sys.stderr, flush=True)


def track_runs(names, flights, vehicles, states_files, nis_files) -> None:
    """One MLflow run per filtered flight, for flights filtered with ``track=False``."""
    for name, f, v, st, nis, rep in zip(names, flights, vehicles, states_files, nis_files, read_reports(nis_files)):
        track_filter(name, f, v, rep, pd.read_parquet(st), nis)


def figures(flight_path, states_path, outdir, title: str = "", vehicle_file=None) -> list[Path]:
    """Filtered vs raw (thesis Figs. 4.2–4.8) for one flight: ``outdir/filter_<quantity>.png`` (the rotor
    speeds in the unit of ``vehicle_file``)."""
    from ..estimation.plots import filtered_vs_raw
    from ..flight import read_flight
    from ..vehicle import load_vehicle

    unit = load_vehicle(vehicle_file).rotor_speed_unit if vehicle_file else None
    return filtered_vs_raw(read_flight(flight_path), pd.read_parquet(states_path), outdir, title, unit)


def summarize(nis_files: dict, out_csv) -> None:
    """One row per flight: each filter's mean NIS, its band and verdict; CSV + Markdown twin, one MLflow run."""
    from ..estimation.run import nis_table
    from ..report.tables import write_table

    table = nis_table(dict(zip(nis_files, read_reports(nis_files.values()))))
    write_table(table, out_csv, title="Filter consistency per flight: mean NIS with the χ² band of the mean, and the "
                "share of samples outside the per-sample χ² band (expected 0.05)")
    share = {f: float(table[f"{f}_ok"].mean()) for f in ("position", "attitude", "rotors")}
    with tracking.run("filter", "summary", config={"flights": len(table)}, inputs=list(nis_files.values())) as run:
        run.metrics({f"consistent_share.{f}": v for f, v in share.items()})
        run.artifact(out_csv)
