"""Stage ``filter``: one canonical flight -> state table (Parquet) + NIS report (JSON) + MLflow run.

Run alone with Hydra (config group ``filter``, ``conf/filter/``)::

    qr filter filter.flight=results/ingest/brushless/eckart00.parquet
    qr filter filter=auto filter.flight=flight.csv filter.vehicle=asctec_hummingbird filter.out=states.parquet

The output defaults to ``<results>/filter/<flight stem>.parquet`` with the report beside it (``.nis.json``).
The computation is :func:`qr.estimation.run.run`; the workflow's batches and tables :mod:`qr.stages.filter_sets`.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from .. import tracking
from ..atomic import atomic_path, write_json
from ..config import hydra_app, to_dict
from ..errors import QrInputError
from ..shipped import vehicle_file as find_vehicle


def nis_path(out: str | Path) -> Path:
    out = Path(out)
    return out.with_name(out.name.removesuffix(".parquet") + ".nis.json")


def run_filter(flight_path, vehicle_file, out, nis_out, filter_cfg: dict, name: str | None = None,
               progress: bool = False, track: bool = True, crossfit_out=None):
    """Filter one flight file, write the state table and the NIS report atomically, track it in MLflow; returns
    the report (:class:`qr.estimation.nis.NisReport`).

    ``track=False`` leaves the MLflow run to :func:`qr.stages.filter_sets.track_runs` (the workflow logs all
    flights' runs from one process: importing MLflow per job would cost more than filtering).
    ``crossfit_out``: also write every airborne segment's matched estimate and its even/odd cross-fitting
    halves (:func:`qr.estimation.crossfit.segment_estimates`), which the diagnoses read instead of filtering
    the flight again."""
    from ..estimation.crossfit import write_segment_estimates
    from ..estimation.run import run
    from ..flight import read_flight
    from ..vehicle import load_vehicle

    flight_path = Path(flight_path)
    name = name or flight_path.stem
    flight = read_flight(flight_path)
    vehicle = load_vehicle(vehicle_file) if vehicle_file else None
    cfg = {k: v for k, v in filter_cfg.items() if k not in ("flight", "out", "vehicle")}
    done = run(flight, vehicle, cfg, name, str(flight_path), progress, crossfit_out is not None)
    with atomic_path(out, suffix=".parquet") as tmp:
        done.states.to_parquet(tmp, index=False)
    if crossfit_out is not None:
        write_segment_estimates(done.crossfit, crossfit_out, cfg, done.report.tuning, vehicle)
    write_json(nis_out, done.report.to_json())
    if track:
        track_filter(name, flight_path, vehicle_file, done.report, done.states, nis_out, done.seconds)
    return done.report


def track_filter(name, flight_path, vehicle_file, report, states, nis_out, seconds=None) -> None:
    """One MLflow run (experiment ``qr-filter``): the report's NIS and noise values, the NIS figure."""
    from ..estimation.plots import nis_figure
    from ..estimation.run import metrics

    inputs = [Path(flight_path)] + ([Path(vehicle_file)] if vehicle_file else [])
    with tracking.run("filter", name, config={"filter": report.config, "vehicle": str(vehicle_file)},
                      inputs=inputs) as run:
        run.metrics(metrics(report, seconds))
        run.tags({"qr.filter": report.filter, "qr.nis_inconsistent": ",".join(report.inconsistent) or "none"})
        run.artifact(nis_out)
        if run.id != "none":  # tracking on: draw the NIS figure for the run
            with tempfile.TemporaryDirectory() as d:
                fig = Path(d) / f"{name.replace('/', '_')}_nis.png"
                nis_figure(states, report, fig, title=name)
                run.artifact(fig)


def _main(cfg) -> None:
    c = to_dict(cfg)
    f = c["filter"]
    if not f.get("flight"):
        raise QrInputError(None, "no flight given", "add filter.flight=PATH (a canonical CSV or Parquet flight)")
    out = Path(f.get("out") or Path(c["results"]) / "filter" / f"{Path(f['flight']).stem}.parquet")
    report = run_filter(f["flight"], find_vehicle(f.get("vehicle") or c["vehicle"]), out, nis_path(out), f,
                        progress=True)
    flagged = ", ".join(report.inconsistent) or "none"
    print(f"wrote {out} and {nis_path(out)} (filter={report.filter}; NIS-inconsistent: {flagged})")


def main() -> None:
    """``qr filter``."""
    hydra_app("filter", _main)


if __name__ == "__main__":
    main()
