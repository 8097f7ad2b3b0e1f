"""Per-flight summary of an ingested log: what arrived, and how far the nominal model is off."""

from __future__ import annotations

import numpy as np
import pandas as pd

from .dynamics import thrust_torque
from .errors import QrInputError
from .estimation.savgol import derivatives
from .flight import POSITION, QUATERNION, ROTORS, dropouts, hover_ratio
from .frames import GRAVITY, quat_to_rot, to_world


def flight_summary(df: pd.DataFrame, vehicle, name: str, source=None) -> dict:
    """Duration, rate, rows, dropouts, hover thrust ratio and the mean residual force (world frame).

    The residual uses Savitzky-Golay accelerations of the mocap position (21
    samples at 100 Hz, cubic) and raw rotor speeds: a pre-filter look, good for
    means, not for per-sample labels.  ``source``: the file, named in errors.
    """
    t = df["t"].to_numpy()
    _check_long_enough(df, source or df.attrs.get("source") or name)
    drop = dropouts(df)
    a_w = derivatives(t, df[POSITION].to_numpy(), order=2)
    q = df[QUATERNION].to_numpy()
    u = df[ROTORS].to_numpy()
    ok = np.isfinite(q).all(axis=1) & np.isfinite(u).all(axis=1)
    R = quat_to_rot(q[ok])
    T, _ = thrust_torque(u[ok], vehicle)
    thrust_w = to_world(R, np.column_stack([np.zeros_like(T), np.zeros_like(T), T]))
    f_w = vehicle.mass * (a_w[ok] - GRAVITY) - thrust_w
    mean_f = f_w.mean(axis=0)
    return {
        "flight": name,
        "vehicle": vehicle.name,
        "duration_s": float(t[-1] - t[0]),
        "rate_hz": float(1.0 / drop["median_dt"]),
        "rows": int(len(df)),
        "mocap_dropouts": drop["mocap_blank"],
        "rotor_dropouts": drop["rotor_blank"],
        "missed_frames": drop["missed_frames"],
        "hover_thrust_ratio": hover_ratio(df, vehicle),
        "mean_fa_world_x": float(mean_f[0]),
        "mean_fa_world_y": float(mean_f[1]),
        "mean_fa_world_z": float(mean_f[2]),
        "std_fa_world_z": float(f_w[:, 2].std()),
    }


def _check_long_enough(df, source):
    from .estimation.savgol import uniform_grid, window

    t = df["t"].to_numpy()
    fix = "summarise a complete flight (seconds of samples), not a fragment"
    if len(t) < 2:
        raise QrInputError(source, f"flight has only {len(t)} sample: no rate, no accelerations", fix)
    n_pos = int(np.isfinite(df[POSITION].to_numpy()).all(axis=1).sum())
    need = window(uniform_grid(t))
    if len(uniform_grid(t)) < need or n_pos < need:
        raise QrInputError(source, f"flight has {len(t)} samples, {n_pos} with a position; the summary's "
                                   f"accelerations need at least {need} (a 0.21 s Savitzky-Golay window)", fix)
    ok = np.isfinite(df[QUATERNION].to_numpy()).all(axis=1) & np.isfinite(df[ROTORS].to_numpy()).all(axis=1)
    if not ok.any():
        raise QrInputError(source, "no sample has both an attitude and four rotor speeds",
                           "check the log: the summary's residual force needs both")


def write_ingest_summary(sets: dict, vehicles: dict, table_path, by_set_path, figure_path) -> pd.DataFrame:
    """Summaries of every ingested flight of every set, a per-set table, a figure and an MLflow run.

    ``sets`` maps a set name to its canonical flight files, ``vehicles`` to its vehicle file.
    """
    from pathlib import Path

    from . import tracking
    from .flight import read_flight
    from .report import figures
    from .report.tables import write_table
    from .vehicle import load_vehicle

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
