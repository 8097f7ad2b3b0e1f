"""The workflow's diagnoses of the measured flight sets (workflow/rules/diagnose.smk), in an engineer's order
(issue 5): diagnose the vehicle without payload first (:func:`diagnose_set`); carry its extended model over to
the payload flights with the payload frame's own mass (:func:`carry_over`); diagnose those; each flight alone
(:func:`diagnose_each`); compare (:func:`summary`).  The filter stage's reports (``.nis.json``: its tuned noise
values, :func:`qr.intake.read_reports`) and cross-fit files are reused, so nothing is tuned or filtered twice.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import yaml

from ..atomic import atomic_dir
from ..intake import read_reports
from ..report.tables import write_table
from ..vehicle import load_vehicle, save_vehicle, vehicle_from_dict
from .diagnose import run_diagnosis, track_diagnosis


def diagnose_set(flights, nis_files, vehicle, out, overrides=(), track=True, estimates=None) -> dict:
    """One diagnosis of all ``flights`` together (canonical flights + their filter reports and, if given,
    the filter stage's cross-fit estimates)."""
    return run_diagnosis(flights, vehicle, out, overrides, track=track, reports=read_reports(nis_files),
                         estimates=estimates)


def diagnose_each(flights, nis_files, vehicle, out_dir, table, overrides=(), estimates=None) -> pd.DataFrame:
    """A diagnosis per flight (no figures: short flights, many of them) and one table of them."""
    rows = []
    reports = read_reports(nis_files)
    estimates = estimates or [None] * len(flights)
    veh = load_vehicle(vehicle)
    with atomic_dir(out_dir) as tmp:
        for f, rep, est in zip(flights, reports, estimates):
            name = Path(f).stem
            doc = run_diagnosis([f], vehicle, tmp / name, overrides, track=False, reports=[rep], figures=False,
                                log=lambda m: None, estimates=[est] if est else None)
            track_diagnosis(f"{Path(out_dir).parent.name}/{name}", doc, [f], tmp / name)
            rows.append({
                "flight": name,
                "effects": ", ".join(e["name"] for e in doc["effects"]) or "-",
                **{f"{e['name']}.{k}" + _unit_suffix(e["name"], k, veh): v for e in doc["effects"]
                   for k, v in e["parameters"].items()},
                "nominal_fz_rmse": doc["nominal"]["force_rmse"][2],
                "extended_fz_rmse": doc["extended"]["force_rmse"][2],
                "noise_fz_rmse": doc["noise_floor"]["force_rmse"][2],
            })
    df = pd.DataFrame(rows)
    write_table(df, table, title=f"Per-flight diagnoses ({Path(out_dir).parent.name})")
    return df


def carry_over(extended_vehicle, base_vehicle, out) -> None:
    """The payload frame = the no-payload diagnosis's extended vehicle with the payload frame's own mass."""
    ext = yaml.safe_load(Path(extended_vehicle).read_text())
    base = load_vehicle(base_vehicle)
    ext["mass"] = base.mass
    ext["name"] = f"{base.name} (effects carried over from {ext.get('name', 'the no-payload diagnosis')})"
    save_vehicle(vehicle_from_dict(ext), out,
                 header=f"{base.name}: mass from {Path(base_vehicle).name}, effects from {extended_vehicle}")


def _unit_suffix(name: str, param: str, vehicle=None) -> str:
    """A table column's unit: ``' (N s/m)'``, nothing for a ratio."""
    from ..effects import DIMENSIONLESS, unit

    u = unit(name, param, vehicle)
    return "" if u in ("", DIMENSIONLESS) else f" ({u})"


def summary(set_dirs: dict, table) -> pd.DataFrame:
    """The set diagnoses side by side: named effects, RMSEs, replay."""
    from ..effects import effects_with_units

    rows = []
    for name, d in set_dirs.items():
        doc = json.loads((Path(d) / "diagnosis.json").read_text())
        eff = effects_with_units(doc["effects"]) or "none"
        rows.append({
            "set": name, "flights": len(doc["flights"]), "samples": doc["samples"], "named": eff,
            "nominal_force_rmse": " / ".join(f"{x:.4f}" for x in doc["nominal"]["force_rmse"]),
            "extended_force_rmse": " / ".join(f"{x:.4f}" for x in doc["extended"]["force_rmse"]),
            "noise_force_rmse": " / ".join(f"{x:.4f}" for x in doc["noise_floor"]["force_rmse"]),
            "nominal_torque_rmse": " / ".join(f"{x:.2e}" for x in doc["nominal"]["torque_rmse"]),
            "extended_torque_rmse": " / ".join(f"{x:.2e}" for x in doc["extended"]["torque_rmse"]),
            "replay_nominal_m": doc["replay"]["nominal_position_rmse"],
            "replay_extended_m": doc["replay"]["extended_position_rmse"],
            "remainder": (doc.get("remainder") or {}).get("correlated_with") or "-",
        })
    df = pd.DataFrame(rows)
    write_table(df, table, title="Diagnoses of the measured flight sets")
    return df
