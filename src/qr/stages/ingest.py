"""Stage ``ingest``: raw logs -> canonical flights, and the summary of what arrived (file I/O and MLflow).

``qr ingest LOG --vehicle V.yaml --out FLIGHT.csv`` and ``qr summary``; the workflow's rules ``ingest`` /
``summary`` are :mod:`qr.stages.ingest_sets`.  The readers (one adapter per source, detection by content) are
:mod:`qr.ingest`; the per-flight summary's numbers are :mod:`qr.ingest.summary`.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from ..errors import QrInputError
from ..ingest import read_log


def ingest(src, vehicle, out, fmt: str = "auto", topics: dict | None = None, align: bool = False,
           report_offsets: bool = False, skip_checks=(), frame: str = "enu-flu", vehicle_file=None) -> pd.DataFrame:
    """Read ``src`` (``fmt`` or detected; written in ``frame``, :data:`qr.flight.FRAMES`), validate it against
    ``vehicle`` (its conventions too: :mod:`qr.conventions`, but ``skip_checks``) and write ``out`` atomically.

    With ``report_offsets`` (``qr ingest``) or ``align`` the gyro's and the rotor stream's time offsets
    against the motion capture are estimated (:mod:`qr.ingest.align`, ``attrs["time_offsets"]``); with
    ``align`` applied. The workflow's ingest does neither (nothing reads the offset there)."""
    from ..flight import write_flight
    from ..intake import check_conventions

    df = read_log(src, vehicle, fmt, topics, frame)
    check_conventions(df, vehicle, src, skip_checks, "--skip-check {name}", vehicle_file)
    if align or report_offsets:
        from ..ingest import align as align_mod  # (scipy.signal: after the log is read)

        found = align_mod.offsets(df, vehicle)
        if align:
            df = align_mod.apply(df, found)
        df.attrs["time_offsets"] = found
    write_flight(df, out)
    return df


def ingest_file(src, vehicle_file, out, fmt: str = "auto", force: bool = False, topics: dict | None = None,
                align: bool = False, skip_checks=(), frame: str = "enu-flu") -> pd.DataFrame:
    """``qr ingest``: ``out`` checked (qr never replaces a file it did not write) before any work."""
    from ..outputs import check_out_file
    from ..vehicle import load_vehicle

    check_out_file(out, inputs=[src, vehicle_file], force=force)
    if Path(out).suffix not in (".csv", ".parquet"):
        raise QrInputError(out, "the output flight must be a .csv or .parquet file", "name --out *.csv or "
                           "*.parquet")
    return ingest(src, load_vehicle(vehicle_file), out, fmt, topics, align, report_offsets=True,
                  skip_checks=skip_checks, frame=frame, vehicle_file=vehicle_file)


def summarise_files(flights, vehicle_file, out, force: bool = False) -> pd.DataFrame:
    """``qr summary``: one row per flight file, ``out`` (CSV) and the same table beside it as Markdown."""
    from ..flight import read_flight
    from ..ingest.summary import flight_summary  # (imported here: qr ingest needs none of it)
    from ..outputs import check_out_file
    from ..report.tables import write_table
    from ..vehicle import load_vehicle

    for o in (out, Path(out).with_suffix(".md")):
        check_out_file(o, inputs=[*flights, vehicle_file], force=force)
    vehicle = load_vehicle(vehicle_file)
    table = pd.DataFrame([flight_summary(read_flight(f), vehicle, Path(f).stem) for f in flights])
    write_table(table, out)
    return table
