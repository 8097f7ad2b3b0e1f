"""The workflow's ingest jobs (workflow/rules/ingest.smk): a set's raw logs read in batches, and the summary of
what arrived (per-flight and per-set tables, a figure, one MLflow run)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from .ingest import ingest


def ingest_batch(srcs, vehicle_file, outs, fmt: str = "auto") -> None:
    """The workflow's ingest job: several raw logs of one set in one process (Python and the readers
    start once per batch, not once per log), each as :func:`ingest` alone."""
    from ..vehicle import load_vehicle

    vehicle = load_vehicle(vehicle_file)
    for src, out in zip(srcs, outs, strict=True):
        df = ingest(src, vehicle, out, fmt=fmt)
        print(f"{src} -> {out}: {len(df)} rows", file=sys.stderr, flush=True)


def write_ingest_summary(sets: dict, vehicles: dict, table_path, by_set_path, figure_path) -> pd.DataFrame:
    """Summaries of every ingested flight of every set, a per-set table, a figure and an MLflow run.

    ``sets`` maps a set name to its canonical flight files, ``vehicles`` to its vehicle file.
    """
    from .. import tracking
    from ..ingest.summary import flight_summary
    from ..flight import read_flight
    from ..report import figures
    from ..report.tables import write_table
    from ..vehicle import load_vehicle

    rows = []
    for name, files in sets.items():
        vehicle = load_vehicle(vehicles[name])
        for f in files:
            row = flight_summary(read_flight(f), vehicle, Path(f).stem)
            rows.append({"set": name, **row})
    table = pd.DataFrame(rows)
    w = table["duration_s"]
    by_set = (table.assign(wz=table["mean_fa_world_z"] * w, wr=table["hover_thrust_ratio"] * w)
              .groupby("set", sort=False)
              .agg(flights=("flight", "size"), vehicle=("vehicle", "first"), duration_s=("duration_s", "sum"),
                   rows=("rows", "sum"), mocap_dropouts=("mocap_dropouts", "sum"), wz=("wz", "sum"),
                   wr=("wr", "sum"), std_between_flights=("mean_fa_world_z", "std"))
              .reset_index())
    by_set["mean_fa_world_z"] = by_set.pop("wz") / by_set["duration_s"]
    by_set["hover_thrust_ratio"] = by_set.pop("wr") / by_set["duration_s"]
    write_table(table, table_path, title="Ingested flights")
    write_table(by_set, by_set_path, title="Per flight set (duration-weighted means)")

    fig, ax = figures.subplots(figsize=(6, 3.2))
    for i, (name, grp) in enumerate(table.groupby("set", sort=False)):
        ax.scatter(np.full(len(grp), i) + np.linspace(-0.15, 0.15, len(grp)), grp["mean_fa_world_z"], s=12,
                   label=f"{name} ({vehicles[name].split('/')[-1]})")
    ax.axhline(-0.0047 * 9.81, color="k", lw=0.8, ls="--", label="4.7 g payload weight")
    ax.axhline(0.0, color="grey", lw=0.5)
    ax.set_xticks(range(table["set"].nunique()), table["set"].unique())
    ax.set_ylabel("mean residual force, world z (N)")
    ax.legend(fontsize=7)
    figures.save(fig, figure_path)

    with tracking.run("ingest", "summary", {"sets": {k: len(v) for k, v in sets.items()}},
                      inputs=[f for v in sets.values() for f in v]) as run:
        run.metrics({f"{r.set}.mean_fa_world_z": r.mean_fa_world_z for r in by_set.itertuples()})
        run.metrics({f"{r.set}.hover_thrust_ratio": r.hover_thrust_ratio for r in by_set.itertuples()})
        for p in (table_path, by_set_path, figure_path):
            run.artifact(p)
    return table
