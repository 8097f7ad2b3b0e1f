"""The simulation study (thesis Chapter 5): :func:`run` ``(sim, study)`` -> :class:`TrackingStudy` or
:class:`StabilityStudy`, with their tables (the CSV rows), MLflow metrics and figures beside them.

Tracking: for each disturbance source of ``simulate.sources`` the plant carries the disturbance and the
Bezier trajectory is flown three ways: nominal controller, compensated by each configured estimate, and the
oracle.  Stability: every linear model of ``simulate.stability.models`` whose inputs include ``a_b`` gets
M_{v,a} (eq. 5.15) and its eigenvalues, then flies in the plant (lagged as the thesis, and implicit) to show
what the eigenvalues predict.  The force-model specs: :mod:`qr.sim.specs`; the stage that writes the tables,
figures and MLflow runs: :mod:`qr.stages.simulate`.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import pandas as pd

from ..errors import QrInputError
from ..vehicle import load_vehicle
from .bezier import from_config as trajectory_from_config
from .stability import Analysis
from .specs import build_force, build_source, check_spec, enabled, no_leak, settings
from .study import ORACLE, Plant, SimSettings, fly

log = logging.getLogger("qr.simulate")
STUDIES = ("tracking", "stability")
FIGURES = {"tracking": {"tracking": "sim_tracking.png", "euler": "sim_euler.png", "rmse": "sim_rmse.png"},
           "stability": {"eigenvalues": "stability_eigenvalues.png", "divergence": "stability_divergence.png"}}
TITLES = {"tracking": "Closed-loop tracking (position RMSE in m)",
          "stability": "Stability with a_b-input force models (eqs. 5.13-5.16)"}


@dataclass(frozen=True)
class Loop:
    """One closed loop of a study: ``key`` (source, controller) or (model, mode), its settings and numbers (its
    MLflow child run's params and metrics) and its flight log."""

    key: tuple[str, str]
    params: dict
    metrics: dict
    log: pd.DataFrame

    @property
    def name(self) -> str:
        return "/".join(self.key)


@dataclass(frozen=True)
class TrackingStudy:
    """One row per source and controller (``table``: tracking.csv) and every loop flown."""

    table: pd.DataFrame
    loops: tuple[Loop, ...]
    figures_source: str  # the source the figures show

    def log(self, source: str, controller: str) -> pd.DataFrame:
        return next(lo.log for lo in self.loops if lo.key == (source, controller))


@dataclass(frozen=True)
class StabilityStudy:
    """One row per a_b-input model (``table``: stability.csv), its eigen-analysis
    (:func:`qr.sim.stability.analyse`) and its loops (lagged, implicit)."""

    table: pd.DataFrame
    analyses: Mapping[str, Analysis]  # model name -> its eigen-analysis
    loops: tuple[Loop, ...]
    max_accel_g: float  # the divergence limit


def studies(task: str) -> tuple[str, ...]:
    """The studies ``simulate.task`` names (``all``: both)."""
    if task not in ("all", *STUDIES):
        raise QrInputError("simulate.task", f"unknown task {task!r}", "use all, tracking or stability")
    return STUDIES if task == "all" else (task,)


def run(sim: dict, study: str, child: Callable[[Loop], None] | None = None, progress: bool = True):
    """The ``study`` (``tracking`` | ``stability``) of ``sim``; ``child(loop)`` after each closed loop."""
    return (tracking_study if study == "tracking" else stability_study)(sim, child, progress)


def simulate_config(overrides=()) -> dict:
    """The resolved ``simulate`` group (Hydra compose with overrides, e.g. ``['simulate=thesis']``)."""
    from ..config import compose, to_dict

    return to_dict(compose(overrides))["simulate"]


# ---- tracking study --------------------------------------------------------------------------

def tracking_study(sim: dict, child=None, progress: bool = True) -> TrackingStudy:
    from tqdm import tqdm

    traj = trajectory_from_config(sim.get("trajectory"))
    cfg_sources = {k: v for k, v in (sim.get("sources") or {}).items() if enabled(v)}
    if not cfg_sources:
        raise QrInputError("simulate.sources", "no enabled disturbance source", "enable at least one source")
    jobs = []
    for name, cfg in cfg_sources.items():
        src = build_source(name, cfg, sim)
        jobs.append((src, "nominal", None, None))
        for est_name, spec in src.estimates.items():
            check_spec(spec, f"simulate.sources.{name}.estimates.{est_name}")
            jobs.append((src, f"compensated:{est_name}", est_name, spec))
        jobs.append((src, "oracle", None, ORACLE))
    rows, loops = [], []
    for src, controller, est_name, spec in tqdm(jobs, desc="tracking", unit="flight", disable=not progress,
                                               file=sys.stderr):
        est = spec if spec is None or spec is ORACLE else build_force(
            spec, src.vehicle, src, f"simulate.sources.{src.name}.estimates.{est_name}")
        if est is not None and est is not ORACLE:
            no_leak(est, f"simulate.sources.{src.name}.estimates.{est_name}")
        res = fly(traj, src.plant, est, src.settings)
        if res.diverged:
            log.warning("%s / %s: %s", src.name, controller, res.message)
        row = {"source": src.name, "vehicle": src.vehicle.name, "controller": controller} | res.metrics() | {
            "message": res.message}
        if est is not None and est is not ORACLE and hasattr(est, "effects"):
            row["estimate"] = _effects_str(est.effects)
        rows.append(row)
        loops.append(Loop((src.name, controller), {"source": src.name, "controller": controller,
                                                   "estimate": spec if isinstance(spec, dict) else str(spec)},
                          row, res.log))
        if child:
            child(loops[-1])
    table = _with_ratios(pd.DataFrame(rows))
    shown = sim.get("figures_source") or table["source"].iloc[0]
    return TrackingStudy(table, tuple(loops), shown if shown in set(table["source"]) else table["source"].iloc[0])


def _effects_str(effects) -> str:
    from ..effects import effects_with_units

    return effects_with_units(effects)


def _with_ratios(df: pd.DataFrame) -> pd.DataFrame:
    """Gain ratios against the nominal and the oracle controller of the same source."""
    out = []
    for _, g in df.groupby("source", sort=False):
        nom = float(g.loc[g["controller"] == "nominal", "rmse"].iloc[0])
        orc = float(g.loc[g["controller"] == "oracle", "rmse"].iloc[0])
        g = g.copy()
        g["ratio_to_nominal"] = g["rmse"] / nom if nom > 0 else 1.0
        g["ratio_to_oracle"] = g["rmse"] / orc if orc > 0 else 1.0
        # share of the improvement the oracle achieves that this controller achieves
        g["gain_captured"] = (nom - g["rmse"]) / (nom - orc) if nom != orc else 1.0
        out.append(g)
    df = pd.concat(out, ignore_index=True)
    cols = ["source", "vehicle", "controller", "status", "rmse_x", "rmse_y", "rmse_z", "rmse", "att_rmse_deg",
            "ratio_to_nominal", "ratio_to_oracle", "gain_captured", "t_end_s", "estimate", "message"]
    if "estimate" not in df:
        df["estimate"] = ""
    df["estimate"] = df["estimate"].fillna("")
    return df[cols]


# ---- stability study -------------------------------------------------------------------------

def stability_study(sim: dict, child=None, progress: bool = True) -> StabilityStudy:
    """The models of ``simulate.stability.models`` whose inputs include ``a_b``."""
    from tqdm import tqdm

    from .stability import analyse, format_eigs

    st = sim.get("stability") or {}
    veh = load_vehicle(st.get("vehicle") or sim["vehicle"])
    veh = veh.with_changes(effects=[]) if veh.effects else veh
    cfg = settings(sim)
    if st.get("duration_s"):
        cfg.duration = float(st["duration_s"])
    step_settings = SimSettings(cfg.rate, cfg.rate, cfg.duration, cfg.gains, cfg.limits, cfg.controller)  # log every step
    dt = 1.0 / cfg.rate
    traj = trajectory_from_config(sim.get("trajectory"))
    sources = {}
    rows, analyses, loops = [], {}, []
    models = {k: v for k, v in (st.get("models") or {}).items() if enabled(v)}
    for name, spec in tqdm(models.items(), desc="stability", unit="model", disable=not progress, file=sys.stderr):
        where = f"simulate.stability.models.{name}"
        src = None
        if str(spec.get("model", "")).startswith("fit_"):
            sname = spec.get("source")
            if sname not in (sim.get("sources") or {}):
                raise QrInputError(where, f"source {sname!r} not in simulate.sources",
                                   "name a tracking source whose plant the identification flight uses")
            src = sources.setdefault(sname, build_source(sname, sim["sources"][sname], sim))
        model = build_force(spec, src.vehicle if src else veh, src, where)
        linear = model.as_linear() if hasattr(model, "as_linear") else model
        if "a_b" not in getattr(linear, "inputs", ()):
            log.info("%s: inputs %s do not include a_b; skipped", name, getattr(linear, "inputs", ()))
            continue
        mass = (src.vehicle if src else veh).mass
        plant_vehicle = src.vehicle if src else veh
        an = analyse(linear.block("v_b"), linear.block("a_b"), mass, dt)
        analyses[name] = an
        row = {"model": name, "inputs": ",".join(linear.inputs), "mass_kg": mass, "dt_s": dt,
               "eigenvalues": format_eigs(an.eigenvalues), "max_abs_eig": an.max_abs_eig,
               "n_above_one": an.n_above_one, "lagged_prediction": an.lagged_prediction,
               "a_block_eigs": format_eigs(an.a_block_eigs),
               "effective_mass_min_real": an.effective_mass_min_real,
               "implicit_prediction": an.implicit_prediction}
        for mode in ("lagged", "implicit"):
            cells, loop = _closed_loop(name, spec, mode, an, Plant(plant_vehicle, [], linear, mode), traj,
                                       step_settings)
            row |= cells
            loops.append(loop)
            if child:
                child(loop)
        rows.append(row)
    if not rows:
        raise QrInputError("simulate.stability.models", "no enabled linear model with a_b among its inputs",
                           "add a model whose inputs include a_b")
    return StabilityStudy(pd.DataFrame(rows), analyses, tuple(loops), cfg.limits.max_accel_g)


def _closed_loop(name: str, spec, mode: str, an, plant: Plant, traj, step_settings: SimSettings):
    """One model flown in closed loop with its a_b fed back ``mode`` (lagged or implicit): the table's cells
    for it and the :class:`Loop` record."""
    from .stability import growth_per_step

    res = fly(traj, plant, None, step_settings)
    f = res.log[["f_true_x", "f_true_y", "f_true_z"]].to_numpy()
    cells = {f"{mode}_status": res.status, f"{mode}_t_end_s": res.t_end, f"{mode}_rmse": res.metrics()["rmse"],
             f"{mode}_growth_per_step": growth_per_step(f) if res.diverged else 1.0, f"{mode}_message": res.message}
    if res.diverged:
        log.warning("%s (%s): %s", name, mode, res.message)
    return cells, Loop((name, mode), {"model": name, "mode": mode, "spec": spec},
                       {"status": res.status, "t_end_s": res.t_end, "rmse": res.metrics()["rmse"],
                        "max_abs_eig": an.max_abs_eig}, res.log)


# ---- what the stage writes and tracks of a study ----------------------------------------------

def metrics(study: TrackingStudy | StabilityStudy) -> dict:
    """The study's MLflow metrics (the tracking study's RMSE per source and controller)."""
    t = study.table
    return {f"{s}.{c}.rmse": r for s, c, r in zip(t["source"], t["controller"], t["rmse"])} \
        if isinstance(study, TrackingStudy) else {}


def figures(study: TrackingStudy | StabilityStudy, paths: dict) -> None:
    """The study's figures (``paths``: :data:`FIGURES`'s keys)."""
    from . import figures as fig

    if isinstance(study, StabilityStudy):
        fig.eigenvalue_figure(study.analyses, paths["eigenvalues"])
        fig.divergence_figure({f"{lo.key[0]} ({lo.key[1]})": lo.log for lo in study.loops}, paths["divergence"],
                              study.max_accel_g)
        return
    src, table = study.figures_source, study.table
    comp = [c for c in table.loc[table["source"] == src, "controller"] if c.startswith("compensated")]
    runs = {"nominal": study.log(src, "nominal")} | ({comp[0]: study.log(src, comp[0])} if comp else {})
    fig.tracking_figure(runs | {"oracle": study.log(src, "oracle")}, paths["tracking"],
                        f"{src}: tracking without and with the disturbance model (thesis Figs. 5.2-5.3)")
    euler_ctrl = comp[0] if comp else "nominal"
    fig.euler_figure(study.log(src, euler_ctrl), paths["euler"],
                     f"{src}, {euler_ctrl}: Euler angles vs desired (thesis Fig. 5.4)")
    fig.rmse_figure(table, paths["rmse"])
