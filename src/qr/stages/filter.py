"""Stage ``filter``: one canonical flight -> state table (Parquet) + NIS report (JSON) + MLflow run.

Run alone with Hydra (config group ``filter``, ``conf/filter/``)::

    qr filter filter.flight=results/ingest/brushless/eckart00.parquet
    qr filter filter=auto filter.flight=flight.csv filter.vehicle=asctec_hummingbird filter.out=states.parquet

The output defaults to ``<results>/filter/<flight stem>.parquet`` with the
report beside it (``.nis.json``).  The workflow's filter jobs call :func:`run_batch`.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from .. import tracking
from ..atomic import atomic_path, write_json
from ..config import compose, hydra_app, to_dict
from ..shipped import vehicle_file as find_vehicle
from ..errors import QrInputError


def nis_path(out: str | Path) -> Path:
    out = Path(out)
    return out.with_name(out.name.removesuffix(".parquet") + ".nis.json")


def _metrics(report: dict, seconds: float) -> dict:
    m = {"inconsistent_filters": len(report["inconsistent"])}
    if seconds is not None:  # (a deferred run has no timing: the report file must stay reproducible)
        m["seconds"] = seconds
    for f, stats in report["nis"].items():
        for name, st in ({"": stats} if "mean" in stats else {f".{k}": v for k, v in stats.items()}).items():
            if st.get("mean") is not None:
                m[f"nis.{f}{name}.mean"] = st["mean"]
                m[f"nis.{f}{name}.consistent"] = float(st["consistent"])
                m[f"nis.{f}{name}.outside_sample_band"] = st["outside_sample_band"]
    for f, noise in report["noise"].items():
        for k, v in noise.items():
            m[f"noise.{f}.{k}"] = v if not isinstance(v, list) else max(v)
    return m


def run_filter(flight_path, vehicle_file, out, nis_out, filter_cfg: dict, name: str | None = None,
               progress: bool = False, track: bool = True, crossfit_out=None) -> dict:
    """Filter one flight file, write the state table and the NIS report atomically, track it in MLflow.

    ``track=False`` leaves the MLflow run to :func:`track_runs` (the workflow logs all flights'
    runs from one process: importing MLflow per job would cost more than filtering).
    ``crossfit_out``: also write every airborne segment's matched estimate and its even/odd
    cross-fitting halves (:func:`qr.estimation.crossfit.segment_estimates`), which the diagnoses read
    instead of filtering the flight again.
    """
    from ..estimation import estimate
    from ..estimation.crossfit import airborne_tuning, fixed_settings, segment_estimates, write_segment_estimates
    from ..flight import read_flight
    from ..vehicle import load_vehicle

    flight_path = Path(flight_path)
    name = name or flight_path.stem
    flight = read_flight(flight_path)
    vehicle = load_vehicle(vehicle_file) if vehicle_file else None
    cfg = {k: v for k, v in filter_cfg.items() if k not in ("flight", "out", "vehicle")}
    start = time.perf_counter()
    tuning = airborne_tuning(flight, vehicle, cfg, progress)
    states, report = estimate(flight, vehicle, fixed_settings(cfg, tuning), progress=progress,
                              source=str(flight_path))
    if tuning is not None:  # the whole flight filtered with the values tuned on its airborne rows
        report.update({k: tuning[k] for k in ("tuning", "tuned_on_s", "nis_note")})
    seconds = time.perf_counter() - start
    report["flight"] = name
    report["config"] = cfg
    with atomic_path(out, suffix=".parquet") as tmp:
        states.to_parquet(tmp, index=False)
    if crossfit_out is not None:
        table, _ = segment_estimates(flight, vehicle, cfg, report)
        write_segment_estimates(table, crossfit_out, cfg, report, vehicle)
    write_json(nis_out, report)
    if track:
        _track(name, flight_path, vehicle_file, report, states, nis_out, seconds)
    return report


def _track(name, flight_path, vehicle_file, report, states, nis_out, seconds=None) -> None:
    from ..estimation.plots import nis_figure

    inputs = [Path(flight_path)] + ([Path(vehicle_file)] if vehicle_file else [])
    with tracking.run("filter", name, config={"filter": report["config"], "vehicle": str(vehicle_file)},
                      inputs=inputs) as run:
        run.metrics(_metrics(report, seconds))
        run.tags({"qr.filter": report["filter"], "qr.nis_inconsistent": ",".join(report["inconsistent"]) or "none"})
        run.artifact(nis_out)
        if run.id != "none":  # tracking on: draw the NIS figure for the run
            with tempfile.TemporaryDirectory() as d:
                fig = Path(d) / f"{name.replace('/', '_')}_nis.png"
                nis_figure(states, report, fig, title=name)
                run.artifact(fig)


def track_runs(names, flights, vehicles, states_files, nis_files) -> None:
    """One MLflow run per filtered flight, for flights filtered with ``track=False``."""
    import json

    import pandas as pd

    for name, f, v, st, nis in zip(names, flights, vehicles, states_files, nis_files):
        _track(name, f, v, json.loads(Path(nis).read_text()), pd.read_parquet(st), nis)


def run_with_overrides(flight_path, vehicle_file, out, nis_out, overrides=(), name=None, track=True,
                       crossfit_out=None) -> dict:
    """Compose the Hydra config with ``overrides`` (``['filter=auto']``) and run :func:`run_filter`."""
    cfg = to_dict(compose(list(overrides)))
    return run_filter(flight_path, vehicle_file or find_vehicle(cfg["vehicle"]), out, nis_out, cfg["filter"], name,
                      track=track, crossfit_out=crossfit_out)


def run_batch(flights, vehicle_file, outs, nis_outs, crossfit_outs, names, overrides=()) -> None:
    """The workflow's filter job: several flights of one set in one process (Python, numba's compiled
    kernels and Hydra start once per batch, not once per flight), each as :func:`run_filter` alone
    (``track=False``: their MLflow runs are logged by :func:`track_runs`)."""
    import sys

    cfg = to_dict(compose(list(overrides)))
    vehicle_file = vehicle_file or find_vehicle(cfg["vehicle"])
    for job in zip(flights, outs, nis_outs, crossfit_outs, names, strict=True):
        flight, out, nis_out, crossfit_out, name = job
        report = run_filter(flight, vehicle_file, out, nis_out, cfg["filter"], name, track=False,
                            crossfit_out=crossfit_out)
        print(f"{name}: filter={report['filter']}, NIS-inconsistent: {', '.join(report['inconsistent']) or 'none'}",
              file=sys.stderr, flush=True)


def figures(flight_path, states_path, outdir, title: str = "", vehicle_file=None) -> list[Path]:
    """Filtered vs raw (thesis Figs. 4.2–4.8) for one flight: ``outdir/filter_<quantity>.png`` (the rotor
    speeds in the unit of ``vehicle_file``)."""
    import pandas as pd

    from ..estimation.plots import filtered_vs_raw
    from ..flight import read_flight
    from ..vehicle import load_vehicle

    unit = load_vehicle(vehicle_file).rotor_speed_unit if vehicle_file else None
    return filtered_vs_raw(read_flight(flight_path), pd.read_parquet(states_path), outdir, title, unit)


def summarize(nis_files: dict, out_csv) -> None:
    """One row per flight: each filter's mean NIS, its band and verdict; CSV + Markdown twin, one MLflow run."""
    import json

    import pandas as pd

    from ..report.tables import write_table

    rows = []
    for name, path in nis_files.items():
        rep = json.loads(Path(path).read_text())
        row = {"flight": name, "filter": rep["filter"], "samples": rep["samples"]}
        for f, st in (("position", rep["nis"]["position"]), ("attitude", rep["nis"]["attitude"]),
                      ("rotors", rep["nis"]["motor"]["all"])):
            row[f"{f}_nis"] = st["mean"]
            row[f"{f}_band"] = "–".join(f"{b:.3g}" for b in st["band"]) if st["band"] else ""
            row[f"{f}_ok"] = st["consistent"]
            row[f"{f}_outside"] = st["outside_sample_band"]  # expected: 1 - confidence
        row["flagged"] = ", ".join(rep["inconsistent"]) or "-"
        rows.append(row)
    table = pd.DataFrame(rows)
    write_table(table, out_csv, title="Filter consistency per flight: mean NIS with the χ² band of the mean, and the "
                "share of samples outside the per-sample χ² band (expected 0.05)")
    share = {f: float(table[f"{f}_ok"].mean()) for f in ("position", "attitude", "rotors")}
    with tracking.run("filter", "summary", config={"flights": len(rows)}, inputs=list(nis_files.values())) as run:
        run.metrics({f"consistent_share.{f}": v for f, v in share.items()})
        run.artifact(out_csv)


def _main(cfg) -> None:
    c = to_dict(cfg)
    f = c["filter"]
    if not f.get("flight"):
        raise QrInputError(None, "no flight given", "add filter.flight=PATH (a canonical CSV or Parquet flight)")
    out = Path(f.get("out") or Path(c["results"]) / "filter" / f"{Path(f['flight']).stem}.parquet")
    report = run_filter(f["flight"], find_vehicle(f.get("vehicle") or c["vehicle"]), out, nis_path(out), f,
                        progress=True)
    flagged = ", ".join(report["inconsistent"]) or "none"
    print(f"wrote {out} and {nis_path(out)} (filter={report['filter']}; NIS-inconsistent: {flagged})")


def main() -> None:
    """``qr filter`` / ``qr filter``."""
    hydra_app("filter", _main)


if __name__ == "__main__":
    main()
