"""Every effect parameter a report or table states carries its unit; every figure axis has its unit.

One short synthetic flight with two hidden effects of different units (a linear drag, N s/m, and a CG
offset, m) goes through ``qr diagnose`` (report and figures), the workflow's summary table and overview,
``qr evaluate``, ``qr learn residual``, the filter stage's figures and the ingest summary; the simulation
study's figures are drawn from small hand-made logs.  The reports and tables are walked line by line:
wherever a named effect appears, each of its parameters' values must be followed by the catalog's unit
(bare only for a ratio).  Every figure is caught at ``savefig`` (in whichever process draws it) and each
axis label must carry a unit in parentheses (or say it is dimensionless: ratio, fraction, count); an axis
without a label must be categorical or share its labelled neighbour's axis.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest
from matplotlib.figure import Figure
from matplotlib.ticker import FixedLocator

from conftest import VEHICLES, run_with_overrides
from qr.effects import CATALOG, DIMENSIONLESS, effects_with_units, unit, with_unit
from qr.vehicle import load_vehicle

HIDDEN = [{"name": "linear_drag", "parameters": {"kx": 0.3, "ky": 0.3, "kz": 0.1}},
          {"name": "cg_offset", "parameters": {"rx": 0.01, "ry": -0.008}}]
CANDIDATES = "diagnose.candidates=[linear_drag,cg_offset,thrust_gain,rotor_drag,mass_error]"
TINY = ["learn.horizon=10", "learn.width=4", "learn.depth=1", "learn.epochs=1", "learn.stride=8", "learn.members=0"]

# ---- what a unit is ----------------------------------------------------------------------------------

BASE_UNITS = {"m", "mm", "cm", "s", "ms", "N", "kg", "rad", "deg", "g", "rpm", "V", "Hz", "%"}
DIMENSIONLESS_WORDS = ("dimensionless", "ratio", "fraction", "count")
NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?"


def is_unit(text: str) -> bool:
    """``'m/s²'``, ``'N m'``, ``'kg m^2'``, ``'N s/m per rpm'``: every factor a base unit (with a power)."""
    tokens = [t for t in re.split(r"[ /·*()]+|per", text.strip()) if t]
    return bool(tokens) and all(re.sub(r"(\^-?\d+|[²³])$", "", t) in BASE_UNITS for t in tokens)


def label_has_unit(label: str) -> bool:
    """A parenthesised group whose head (before ':', ';' or ',') is a unit or a dimensionless word."""
    for group in re.findall(r"\(([^()]*)\)", label):
        head = re.split(r"[:;,]", group)[0].strip()
        if head.startswith(DIMENSIONLESS_WORDS) or is_unit(head):
            return True
    return False


def test_the_unit_rules_themselves():
    assert is_unit("m/s²") and is_unit("N m") and is_unit("kg m^2") and is_unit("N s/m per rpm")
    assert not is_unit("vehicle unit") and not is_unit("") and not is_unit("0: the vehicle")
    assert label_has_unit("t (s), held-out part") and label_has_unit("epoch (count; 0: the start)")
    assert not label_has_unit("mean absolute error") and not label_has_unit("u1 (vehicle unit)")
    assert not label_has_unit("epoch (0: the vehicle without the residual)")


def test_every_catalog_unit_is_a_unit_or_a_ratio(hummingbird):
    """Whatever effects the catalog holds (and gains later): each parameter's unit is one."""
    for name, eff in CATALOG.items():
        assert len(eff.units) == len(eff.params), name
        for p in eff.params:
            u = unit(name, p, hummingbird)
            assert u == DIMENSIONLESS or is_unit(u), (name, p, u)
    assert unit("rotor_drag", "k", hummingbird) == "N s/m per rpm"
    assert with_unit("linear_drag", "kx", 0.3) == "0.3 N s/m" and with_unit("thrust_gain", "gain", 1.1) == "1.1"
    every = [{"name": n, "parameters": dict(zip(e.params, np.linspace(0.1, 0.9, len(e.params))))}
             for n, e in CATALOG.items()]
    _assert_values_carry_units(effects_with_units(every, hummingbird), "effects_with_units", hummingbird,
                               expect=sum(len(e.params) for e in CATALOG.values()))


# ---- the walk over what qr writes ----------------------------------------------------------------------

def _axis_info(ax, which: str) -> dict:
    axis = getattr(ax, f"{which}axis")
    label = axis.get_label().get_text()
    shared = getattr(ax, f"get_shared_{which}_axes")().get_siblings(ax) if which != "z" else [ax]
    labelled = any(getattr(a, f"get_{which}label")() for a in shared if a is not ax)
    # categories: ticks placed by hand and labelled with words (a bar per source and controller)
    words = [t.get_text() for t in axis.get_ticklabels() if re.search(r"[A-Za-z]", t.get_text())]
    return {"label": label, "shared_labelled": labelled,
            "categorical": isinstance(axis.get_major_locator(), FixedLocator) and bool(words)}


def _record_labels(fig: Figure, fname, record) -> None:
    axes = []
    for ax in fig.get_axes():
        if not ax.axison:
            continue
        axes.append({w: _axis_info(ax, w) for w in ("x", "y", "z") if hasattr(ax, f"{w}axis")})
    with open(record, "a") as f:  # appended from a forked child too (the anatomy figure)
        f.write(json.dumps({"file": str(fname), "axes": axes}) + "\n")


def _sim_logs(n=200):
    from qr.sim.study import RD_COLUMNS

    t = np.linspace(0, 2, n)
    log = pd.DataFrame({"t": t, "px": np.sin(t), "py": np.cos(t), "pz": 1 + 0.1 * t, "qw": np.cos(0.1 * t / 2),
                        "qx": 0.0, "qy": 0.0, "qz": np.sin(0.1 * t / 2), "ax": 0.1, "ay": 0.0, "az": 0.2})
    for c in ("px", "py", "pz"):
        log[f"ref_{c}"] = log[c] + 0.001
    log[RD_COLUMNS] = log[["qw", "qx", "qy", "qz"]].to_numpy()
    return log


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """Everything the chain writes for one synthetic diagnosis, every figure's axis labels recorded."""
    from qr.estimation.plots import nis_figure
    from qr.report.overview import overview_html
    from qr.sim import figures as sim_figures
    from qr.sim.stability import analyse
    from qr.sim.synth import SynthConfig, write_synth
    from qr.stages import filter_sets as filter_stage
    from qr.stages.diagnose import run_diagnosis
    from qr.stages.diagnose_sets import summary
    from qr.stages.evaluate import run_evaluation
    from qr.stages.ingest_sets import write_ingest_summary
    from qr.stages.learn_residual import run_residual

    d = tmp_path_factory.mktemp("units")
    record = d / "labels.jsonl"
    savefig = Figure.savefig

    def recording(self, fname, *args, **kwargs):
        _record_labels(self, fname, record)
        return savefig(self, fname, *args, **kwargs)

    mp = pytest.MonkeyPatch()
    mp.setattr(Figure, "savefig", recording)
    mp.setenv("QR_TRACKING", "off")
    quiet = lambda m: None  # noqa: E731
    try:
        write_synth(d / "s", load_vehicle(VEHICLES / "asctec_hummingbird.yaml"), HIDDEN, SynthConfig(duration=20, seed=1))
        flight, vehicle = d / "s" / "flight.csv", d / "s" / "vehicle.yaml"
        doc = run_diagnosis([flight], vehicle, d / "diag", [CANDIDATES], track=False, log=quiet)
        summary({"synth": d / "diag"}, d / "tables" / "diagnosis_summary.csv")
        overview = overview_html(pd.read_csv(d / "tables" / "diagnosis_summary.csv"), None, {}, [])
        (d / "overview.html").write_text(overview)
        run_evaluation([flight], [vehicle, d / "diag" / "extended_vehicle.yaml"], d / "ev", ["evaluate.horizon=20"],
                       log=quiet)
        run_residual([flight], d / "diag" / "extended_vehicle.yaml", d / "res", TINY, track=False, log=quiet)
        report = run_with_overrides(flight, vehicle, d / "states.parquet", d / "states.nis.json", track=False)
        filter_stage.figures(flight, d / "states.parquet", d / "filter", "synth", vehicle)
        nis_figure(pd.read_parquet(d / "states.parquet"), report, d / "filter" / "nis.png")
        write_ingest_summary({"synth": [str(flight)]}, {"synth": str(vehicle)}, d / "tables" / "ingest.csv",
                             d / "tables" / "ingest_by_set.csv", d / "ingest.png")
        log = _sim_logs()
        sim_figures.tracking_figure({"nominal": log, "oracle": log}, d / "sim_tracking.png", "tracking")
        sim_figures.euler_figure(log, d / "sim_euler.png", "attitude")
        sim_figures.rmse_figure(pd.DataFrame({"source": ["a", "a"], "controller": ["nominal", "oracle"],
                                              "rmse": [0.01, 0.005], "status": ["ok", "ok"]}), d / "sim_rmse.png")
        hover = analyse(np.diag([0.5, 0.5, 0.5]), np.zeros((3, 3)), 1.0, 0.01)  # a stable model's eigen-analysis
        sim_figures.eigenvalue_figure({"nominal": hover}, d / "sim_eigenvalues.png")
        sim_figures.divergence_figure({"lagged": log, "implicit": log}, d / "sim_divergence.png", 3.0)
    finally:
        mp.undo()
    return d, doc


def _assert_values_carry_units(text: str, where: str, vehicle, expect: int) -> None:
    """Each value of a parameter of an effect is followed by its unit: the text from an effect's name (as code,
    ``linear_drag``, or in words, ``linear drag``) to the next effect's name, on one line, is that effect's."""
    seen = 0
    names = "|".join(rf"{n}|{n.replace('_', ' ')}" for n in sorted(CATALOG, key=len, reverse=True))
    for line in re.split(r"\n|</li>", text):
        marks = list(re.finditer(rf"(?<![\w-])({names})(?![\w-])", line))
        for k, mark in enumerate(marks):
            name = mark.group(1).replace(" ", "_")
            segment = line[mark.end():marks[k + 1].start() if k + 1 < len(marks) else len(line)]
            for p in CATALOG[name].params:
                for m in re.finditer(rf"(?<![\w.]){re.escape(p)}\s*=\s*{NUM}(?:\s*±\s*{NUM})?", segment):
                    rest = segment[m.end():]
                    u = unit(name, p, vehicle)
                    shown = {u, u.replace("^2", "²"), unit(name, p)}  # the generic rotor-speed unit where unknown
                    if u == DIMENSIONLESS:
                        assert not re.match(r"\s*[A-Za-z]", rest), (where, segment)
                    else:
                        assert any(rest.startswith(" " + s) for s in shown), (where, name, p, segment)
                    seen += 1
    assert seen >= expect, (where, seen, text[:2000])


def test_reports_and_tables_state_each_parameter_with_its_unit(written, hummingbird):
    d, doc = written
    named = sum(len(e["parameters"]) for e in doc["effects"])
    assert [e["name"] for e in doc["effects"]] == ["linear_drag", "cg_offset"]  # two units to check
    for path, vehicle in ((d / "diag" / "report.md", hummingbird), (d / "tables" / "diagnosis_summary.csv", None),
                          (d / "tables" / "diagnosis_summary.md", None), (d / "overview.html", None)):
        _assert_values_carry_units(path.read_text(), path.name, vehicle, expect=named)
    for path in (d / "ev" / "report.md", d / "res" / "report.md"):  # no effect parameter stated: none unitless
        _assert_values_carry_units(path.read_text(), path.name, hummingbird, expect=0)


def test_every_figure_axis_has_its_unit(written):
    d, _ = written
    figures = [json.loads(line) for line in (d / "labels.jsonl").read_text().splitlines()]
    # the file each figure goes to (written to a temporary name beside it first: ".NAME.png.qrtmp-...")
    names = [re.match(r"\.?([^.]+)", f["file"].rsplit("/", 1)[-1]).group(1) for f in figures]
    # the diagnosis's residual and anatomy figures are drawn by forked children into "figure.png" (qr.report.
    # background), then moved
    assert names.count("figure") == 2
    expected = {"figure", "replay_drift", "rollout_mae", "training_curve",
                "filter_position", "filter_velocity", "filter_acceleration", "filter_quaternion",
                "filter_angular_velocity", "filter_angular_acceleration", "filter_rotors", "nis", "ingest",
                "sim_tracking", "sim_euler", "sim_rmse", "sim_eigenvalues", "sim_divergence"}
    assert expected <= set(names), sorted(names)
    checked = 0
    for f in figures:
        for ax in f["axes"]:
            for which, info in ax.items():
                if info["label"]:
                    assert label_has_unit(info["label"]), (f["file"], which, info["label"])
                    checked += 1
                else:
                    assert info["categorical"] or info["shared_labelled"], (f["file"], which, ax)
    assert checked > 60


def test_the_refinement_table_states_each_row_s_unit():
    """``diagnose.refine=rollout``'s table in report.md: each row's unit, the catalog's for a named effect's
    parameter (N s/m for linear_drag's kx, m for the CG), kg m² for J and the rotors' inertia, "–" for a gain
    or ratio; each stated unit passes :func:`is_unit`."""
    from qr.diagnose.refine import report_lines

    def row(effect, parameter, label, named=True):
        return {"effect": effect, "parameter": parameter, "label": label, "named": named, "reference": 0.001,
                "physical_range": [0.0, 1.0], "one_step": 0.1, "one_step_stderr": 0.01, "rollout": 0.12,
                "rollout_stderr": 0.01, "bound_hit": None, "z": 1.4, "written": 0.12, "in_range": True}

    rows = [row("linear_drag", "kx", "linear_drag kx"), row("cg_offset", "rx", "cg_offset rx"),
            row("inertia_error", "dJxx", "J_xx", False), row("thrust_gain", "gain", "C_T (gain)", False),
            row("rotor_inertia", "value", "rotor inertia", False),
            row("flapping_pitch_ratio", "value", "flapping pitch/roll", False)]
    block = {"horizon": 50, "windows": 10, "stride": 5, "iterations": 3, "stopped": "converged", "wall_s": 1.0,
             "covariance": "sandwich", "parameters": rows, "training": {"ratio_to_rate_frozen_at_H": {}},
             "held_out": {"ratio_to_rate_frozen_at_H": {}}, "statements": []}
    table = [ln for ln in report_lines(block) if ln.startswith("| ") and "---" not in ln]
    assert table[0].split("|")[2].strip() == "unit"
    units = {ln.split("|")[1].strip(): ln.split("|")[2].strip() for ln in table[1:]}
    assert units == {"linear_drag kx": "N s/m", "cg_offset rx": "m", "J_xx (vehicle)": "kg m²",
                     "C_T (gain) (vehicle)": "–", "rotor inertia (vehicle)": "kg m²",
                     "flapping pitch/roll (vehicle)": "–"}
    assert all(is_unit(u.replace("²", "^2")) or u == "–" for u in units.values())
