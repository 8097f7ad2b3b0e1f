"""The learning stage's tables: thesis Tables 3.1, 3.2, 4.2, 4.3 (same columns, our numbers) and the GPR grid.

Inputs are sweep directories written by ``python -m qr.learn -m sweep=...``
(``runs/*.json``).  Every ANN table starts with row 0, the nominal model (it
predicts no residual, so its RMSE is that of the labels on the same test
samples), and adds to the thesis's columns the RMSE as a share of the nominal
one, whether the row leaks its target, and the thesis's own RMSE for the row.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from ..datasets import TARGET_UNITS
from .tables import write_table

SYMBOL = {"v_b": "v_b", "a_b": "a_b", "p": "p", "p_z": "p_z", "q": "q", "omega": "ω", "alpha": "α",
          "u": "u", "u2": "u²"}
ACTIVATION = {"linear": "Linear", "relu": "ReLU", "tanh": "tanh"}
AXIS = {"f_a": ("f_x", "f_y", "f_z"), "tau_a": ("τ_x", "τ_y", "τ_z")}


def records(sweep_dir) -> list[dict]:
    """Run records of a sweep directory, in row order (then name)."""
    recs = [json.loads(p.read_text()) for p in sorted(Path(sweep_dir, "runs").glob("*.json"))]
    return sorted(recs, key=lambda r: (r.get("row") is None, r.get("row") or 0, r["name"]))


def _inputs(names) -> str:
    return ", ".join(SYMBOL.get(n, n) for n in names)


def ann_table(recs: list[dict]) -> pd.DataFrame:
    """Thesis Table 4.2 / 4.3 layout: one row per architecture, row 0 the nominal model."""
    if not recs:
        raise ValueError("no runs to tabulate")
    target = recs[0]["target"]
    unit = TARGET_UNITS[target]
    nominal = {r["metrics"]["nominal_rmse"] for r in recs}
    if max(nominal) - min(nominal) > 1e-12 * max(nominal):
        raise ValueError("runs of one table were tested on different samples")
    rows = [{"Model No.": 0, "Inputs": "Nominal model", "No. of hidden layers": "-",
             "No. of hidden layer neurons": "-", "Activation function": "-", f"RMSE ({unit})": min(nominal),
             "RMSE / nominal (%)": 100.0, "leaks target": False,
             f"thesis RMSE ({unit})": recs[0].get("thesis_nominal")}]
    for r in recs:
        m = r["model"]
        rows.append({"Model No.": r.get("row") if r.get("row") is not None else r["name"],
                     "Inputs": _inputs(r["inputs"]), "No. of hidden layers": m.get("layers"),
                     "No. of hidden layer neurons": m.get("neurons"),
                     "Activation function": ACTIVATION.get(m.get("activation"), m.get("activation")),
                     f"RMSE ({unit})": r["metrics"]["rmse"], "RMSE / nominal (%)": 100 * r["metrics"]["ratio"],
                     "leaks target": bool(r["leaks_target"]), f"thesis RMSE ({unit})": r.get("thesis")})
    return pd.DataFrame(rows)


def _thesis_gpr(recs: list[dict]) -> dict:
    """The GPR run of the thesis's set-up: squared-exponential ARD kernel on v_b (else the first)."""
    for r in recs:
        if r["kind"] == "gpr" and r["model"].get("kernel") == "se_ard" and r["inputs"] == ["v_b"]:
            return r
    return next(r for r in recs if r["kind"] == "gpr")


def hyperparameter_table(recs: list[dict]) -> pd.DataFrame:
    """Thesis Table 3.1: initial and trained GP hyperparameters per output axis (data units)."""
    r = _thesis_gpr(recs)
    rows = []
    for axis, hp in zip(AXIS[r["target"]], r["info"]["hyperparameters"]):
        for h in hp:
            rows.append({"Output": axis, "Hyperparameter": h["name"], "Initialized value": h["initial"],
                         "Trained value": h["trained"]})
    return pd.DataFrame(rows)


def basis_table(recs: list[dict]) -> pd.DataFrame:
    """Thesis Table 3.2: coefficients of the linear basis ``h(x) = [1, x]`` per output axis."""
    r = _thesis_gpr(recs)
    basis = r["info"].get("basis") or []
    rows = [{"Output": axis, "Coefficient": k, "Trained value": v}
            for axis, b in zip(AXIS[r["target"]], basis) for k, v in b.items()]
    return pd.DataFrame(rows, columns=["Output", "Coefficient", "Trained value"])


def gpr_table(recs: list[dict]) -> pd.DataFrame:
    """The GPR grid: test RMSE, share of nominal, 95 % band coverage and train time per kernel and inputs."""
    unit = TARGET_UNITS[recs[0]["target"]]
    rows = [{"Kernel": r["model"]["kernel"], "Mean": r["model"]["mean"], "Inputs": _inputs(r["inputs"]),
             f"RMSE ({unit})": r["metrics"]["rmse"], f"nominal RMSE ({unit})": r["metrics"]["nominal_rmse"],
             "RMSE / nominal (%)": 100 * r["metrics"]["ratio"], "95 % coverage (%)": 100 * r["metrics"]["coverage95"],
             "train time (s)": r["metrics"]["train_time_s"], "training samples": r["metrics"]["n_train"],
             "sparse (DTC)": bool(r["info"].get("sparse"))} for r in recs if r["kind"] == "gpr"]
    return pd.DataFrame(rows)


def write_learning_tables(sweeps: dict, out: dict) -> None:
    """``sweeps``: sweep name -> directory; ``out``: table name -> CSV path (Markdown twin beside it)."""
    force, torque, gpr = (records(sweeps[k]) for k in ("table_4_2", "table_4_3", "gpr_kernels"))
    write_table(hyperparameter_table(gpr), out["table_3_1"],
                title="Table 3.1: GP hyperparameters (squared-exponential ARD kernel, inputs v_b)")
    write_table(basis_table(gpr), out["table_3_2"], title="Table 3.2: coefficients of the basis function [1, v_b]")
    write_table(ann_table(force), out["table_4_2"], title="Table 4.2: ANN architectures learning f_a")
    write_table(ann_table(torque), out["table_4_3"], title="Table 4.3: ANN architectures learning τ_a")
    write_table(gpr_table(gpr), out["gpr_kernels"], title="GPR kernels learning f_a")
