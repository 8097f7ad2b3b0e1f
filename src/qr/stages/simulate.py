"""Simulation study (thesis Chapter 5): ``qr simulate [simulate=thesis] [simulate.task=tracking|stability|all]``.

Tracking: for each disturbance source of ``simulate.sources`` the plant carries the
disturbance and the Bezier trajectory is flown three ways: nominal controller,
compensated by each configured estimate, and the oracle.  Stability: every
linear model of ``simulate.stability.models`` whose inputs include ``a_b`` gets
M_{v,a} (eq. 5.15) and its eigenvalues, then flies in the plant (lagged as the
thesis, and implicit) to show what the eigenvalues predict.  Tables go to
``results/simulation/`` (CSV + Markdown), figures to ``results/figures/``, and
every closed loop is an MLflow run (experiments ``qr-simulate``, ``qr-stability``).

Force-model specs (``plant.force``, ``estimates.*``, ``stability.models.*``)::

    {model: thesis_model8, u_scale: 1e4}                    # eq. 4.38 on [v_b, u]
    {model: linear, inputs: [v_b, u], W: [[...]], b: [...], u_scale: 1, per_mass: false}
    {model: effects, effects: ["linear_drag:kx=0.3", ...]}  # catalog terms
    {model: extended_vehicle, path: extended_vehicle.yaml}  # qr diagnose's output
    {model: learned, path: DIR}                             # qr.models.load (learning stage)
    {model: fit_linear, inputs: [v_b, u]}                   # least squares on an identification flight
    {model: fit_effects, effects: [linear_drag, wind_force]}
"""

from __future__ import annotations

import logging
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ..effects import parse_effect_spec, validate_effect_list
from ..errors import QrInputError
from ..sim import disturbance as dist
from ..sim.bezier import from_config as trajectory_from_config
from ..sim.control import Gains
from ..sim.study import ORACLE, Limits, Plant, SimSettings, fly, identification_data
from ..vehicle import load_vehicle

log = logging.getLogger("qr.simulate")
FIGURES = {"tracking": "sim_tracking.png", "euler": "sim_euler.png", "rmse": "sim_rmse.png"}
STABILITY_FIGURES = {"eigenvalues": "stability_eigenvalues.png", "divergence": "stability_divergence.png"}


# ---- configuration -> objects --------------------------------------------------------------

def settings(sim: dict) -> SimSettings:
    for key, cls in (("gains", Gains), ("limits", Limits)):
        bad = sorted(set(sim.get(key) or {}) - set(cls.__dataclass_fields__))
        if bad:
            raise QrInputError(f"sim.{key}", f"unknown key(s) {bad}", f"use {sorted(cls.__dataclass_fields__)}")
    rate = float(sim.get("rate", 1000.0))
    if rate < 500:
        raise QrInputError("simulate.rate", f"{rate} Hz is below 500 Hz", "simulate at 500 Hz or more (RK4 + rotor lag)")
    controller = sim.get("controller", "lqr")
    if controller not in ("lqr", "lee"):
        raise QrInputError("simulate.controller", f"{controller!r} is not lqr or lee", "simulate.controller=lee")
    return SimSettings(rate=rate, log_rate=float(sim.get("log_rate", 100.0)), duration=sim.get("duration"),
                       gains=Gains(**(sim.get("gains") or {})), limits=Limits(**(sim.get("limits") or {})),
                       controller=controller)


def parse_effects(items, where, vehicle=None) -> list[dict]:
    """Catalog effects given as ``'name:p=v,...'`` specs or ``{name, parameters}`` (in range for ``vehicle``)."""
    out = []
    for e in items or []:
        out.append(parse_effect_spec(e, vehicle) if isinstance(e, str) else e)
    return validate_effect_list(out, where, vehicle)


@dataclass
class Source:
    """A disturbance source: the nominal vehicle, the TRUE plant, and how to identify it."""

    name: str
    vehicle: object
    plant: Plant
    estimates: dict = field(default_factory=dict)
    ident_cfg: dict = field(default_factory=dict)
    settings: SimSettings = field(default_factory=SimSettings)
    _ident: tuple | None = None

    def identification(self):
        if self._ident is None:
            c = self.ident_cfg
            self._ident = identification_data(self.plant, float(c.get("duration_s", 60.0)), int(c.get("seed", 0)),
                                              float(c.get("accel_noise_m_s2", 0.0)), self.settings)
        return self._ident


KINDS = ("thesis_model8", "linear", "effects", "extended_vehicle", "learned", "fit_linear", "fit_effects")


def check_spec(spec, where: str) -> None:
    """Fail before any flight on a spec that cannot be built."""
    kind = (spec or {}).get("model")
    if kind not in KINDS:
        raise QrInputError(where, f"unknown force model {kind!r}", f"use model: {' | '.join(KINDS)}")
    if kind in ("extended_vehicle", "learned"):
        _path(spec, where)


def build_force(spec: dict, vehicle, source: Source | None, where: str):
    """A force model from a spec (see the module docstring)."""
    spec = dict(spec or {})
    kind = spec.get("model")
    name = spec.get("name", where.rsplit(".", 1)[-1])
    if kind == "thesis_model8":
        return dist.thesis_model8(float(spec.get("u_scale", dist.MODEL8_U_SCALE)))
    if kind == "linear":
        scale = vehicle.mass if spec.get("per_mass") else 1.0
        W = scale * np.asarray(spec["W"], dtype=float)
        b = scale * np.asarray(spec.get("b", [0, 0, 0]), dtype=float)
        return dist.LinearForce(W, b, tuple(spec["inputs"]), name, float(spec.get("u_scale", 1.0)))
    if kind == "effects":
        return dist.CatalogForce(parse_effects(spec.get("effects"), where, vehicle), vehicle, name)
    if kind == "extended_vehicle":
        nominal, effects = dist.extended_vehicle(_path(spec, where))
        return dist.CatalogForce(effects, nominal, name)
    if kind == "learned":
        return dist.LearnedForce(_path(spec, where), name)
    if kind in ("fit_linear", "fit_effects"):
        if source is None:
            raise QrInputError(where, f"'{kind}' needs a plant to fly an identification flight in",
                               "name the tracking source to identify in with 'source:'")
        s, f_a = source.identification()
        if kind == "fit_linear":
            return dist.fit_linear(s, f_a, tuple(spec["inputs"]), name, float(spec.get("u_scale", 1.0)))
        return dist.fit_effects(s, f_a, list(spec["effects"]), source.vehicle, name)
    check_spec(spec, where)
    raise AssertionError(kind)  # pragma: no cover


def _path(spec, where):
    p = spec.get("path")
    if not p:
        raise QrInputError(where, "no path given", f"set {where}.path (or disable the source with enabled: false)")
    return p


def _no_leak(model, where):
    if "a_b" in getattr(model, "inputs", ()):
        raise QrInputError(where, "the model takes a_b, from which its label f_a is computed (it leaks the target)",
                           "use it in simulate.stability.models, not as a tracking disturbance or estimate")


def build_source(name: str, cfg: dict, sim: dict) -> Source:
    where = f"simulate.sources.{name}"
    veh = load_vehicle(cfg.get("vehicle") or sim["vehicle"])
    effects = validate_effect_list(veh.effects, where) + parse_effects((cfg.get("plant") or {}).get("effects"), where,
                                                                       veh)
    nominal = veh.with_changes(effects=[]) if veh.effects else veh
    pc = cfg.get("plant") or {}
    src = Source(name, nominal, Plant(nominal, effects), dict(cfg.get("estimates") or {}),
                 dict(sim.get("identification") or {}), settings(sim))
    if pc.get("force"):
        src.plant.force = build_force(pc["force"], nominal, None, f"{where}.plant.force")
        _no_leak(src.plant.force, f"{where}.plant.force")
    return src


def enabled(cfg: dict) -> bool:
    return bool((cfg or {}).get("enabled", True))


# ---- tracking study --------------------------------------------------------------------------

def tracking_study(sim: dict, tracked=None, progress: bool = True):
    """``(table, logs)``: one row per source and controller; ``logs[(source, controller)]`` flight logs."""
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
    rows, logs = [], {}
    for src, controller, est_name, spec in tqdm(jobs, desc="tracking", unit="flight", disable=not progress,
                                               file=sys.stderr):
        est = spec if spec is None or spec is ORACLE else build_force(
            spec, src.vehicle, src, f"simulate.sources.{src.name}.estimates.{est_name}")
        if est is not None and est is not ORACLE:
            _no_leak(est, f"simulate.sources.{src.name}.estimates.{est_name}")
        res = fly(traj, src.plant, est, src.settings)
        if res.diverged:
            log.warning("%s / %s: %s", src.name, controller, res.message)
        row = {"source": src.name, "vehicle": src.vehicle.name, "controller": controller} | res.metrics() | {
            "message": res.message}
        if est is not None and est is not ORACLE and hasattr(est, "effects"):
            row["estimate"] = _effects_str(est.effects)
        rows.append(row)
        logs[(src.name, controller)] = res.log
        _track_child(tracked, f"{src.name}/{controller}", {"source": src.name, "controller": controller,
                                                       "estimate": spec if isinstance(spec, dict) else str(spec)},
                     row)
    return _with_ratios(pd.DataFrame(rows)), logs


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


@dataclass
class _Run:
    """The parent MLflow run of a study; every closed loop is a child run."""

    stage: str
    handle: object


def _track_child(parent: _Run | None, name, params, metrics):
    if parent is None:
        return
    from .. import tracking

    with tracking.run(parent.stage, name, params, parent=parent.handle,
                      tags={"qr.status": metrics.get("status", "")}) as r:
        r.metrics({k: v for k, v in metrics.items() if isinstance(v, (int, float))})


def tracking_figures(sim: dict, table: pd.DataFrame, logs: dict, paths: dict) -> None:
    from ..sim import figures

    src = sim.get("figures_source") or table["source"].iloc[0]
    if src not in set(table["source"]):
        src = table["source"].iloc[0]
    g = table[table["source"] == src]
    comp = [c for c in g["controller"] if c.startswith("compensated")]
    runs = {"nominal": logs[(src, "nominal")]}
    if comp:
        runs[comp[0]] = logs[(src, comp[0])]
    runs["oracle"] = logs[(src, "oracle")]
    figures.tracking_figure(runs, paths["tracking"],
                            f"{src}: tracking without and with the disturbance model (thesis Figs. 5.2-5.3)")
    euler_ctrl = comp[0] if comp else "nominal"
    figures.euler_figure(logs[(src, euler_ctrl)], paths["euler"],
                         f"{src}, {euler_ctrl}: Euler angles vs desired (thesis Fig. 5.4)")
    figures.rmse_figure(table, paths["rmse"])


# ---- stability study -------------------------------------------------------------------------

def stability_study(sim: dict, tracked=None, progress: bool = True):
    """``(table, analyses, logs)`` for ``simulate.stability.models`` whose inputs include ``a_b``."""
    from tqdm import tqdm

    from ..sim.stability import analyse, format_eigs, growth_per_step

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
    rows, analyses, logs = [], {}, {}
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
               "eigenvalues": format_eigs(an["eigenvalues"]), "max_abs_eig": an["max_abs_eig"],
               "n_above_one": an["n_above_one"], "lagged_prediction": an["lagged_prediction"],
               "a_block_eigs": format_eigs(an["a_block_eigs"]),
               "effective_mass_min_real": an["effective_mass_min_real"],
               "implicit_prediction": an["implicit_prediction"]}
        for mode in ("lagged", "implicit"):
            res = fly(traj, Plant(plant_vehicle, [], linear, mode), None, step_settings)
            f = res.log[["f_true_x", "f_true_y", "f_true_z"]].to_numpy()
            row |= {f"{mode}_status": res.status, f"{mode}_t_end_s": res.t_end,
                    f"{mode}_rmse": res.metrics()["rmse"],
                    f"{mode}_growth_per_step": growth_per_step(f) if res.diverged else 1.0,
                    f"{mode}_message": res.message}
            if res.diverged:
                log.warning("%s (%s): %s", name, mode, res.message)
            logs[f"{name} ({mode})"] = res.log
            _track_child(tracked, f"{name}/{mode}", {"model": name, "mode": mode, "spec": spec},
                         {"status": res.status, "t_end_s": res.t_end, "rmse": res.metrics()["rmse"],
                          "max_abs_eig": an["max_abs_eig"]})
        rows.append(row)
    if not rows:
        raise QrInputError("simulate.stability.models", "no enabled linear model with a_b among its inputs",
                           "add a model whose inputs include a_b")
    return pd.DataFrame(rows), analyses, logs


# ---- outputs ---------------------------------------------------------------------------------

def _open_run(stage, sim, inputs):
    from .. import tracking

    return tracking.run(stage, f"{stage}:{sim.get('name', 'sim')}", sim, inputs)


def write_tracking(sim: dict, table_path, figure_paths: dict | None = None, inputs=()) -> pd.DataFrame:
    """Run the tracking study and write ``tracking.csv`` (+ .md) and its figures; one MLflow run each."""
    from ..report.tables import write_table

    figure_paths = figure_paths or {k: Path(table_path).parents[1] / "figures" / v for k, v in FIGURES.items()}
    with _open_run("simulate", sim, inputs) as handle:
        table, logs = tracking_study(sim, _Run("simulate", handle))
        write_table(table, table_path, title="Closed-loop tracking (position RMSE in m)")
        tracking_figures(sim, table, logs, figure_paths)
        handle.metrics({f"{s}.{c}.rmse": r for s, c, r in zip(table["source"], table["controller"], table["rmse"])})
        for p in [table_path, *figure_paths.values()]:
            handle.artifact(p)
    return table


def write_stability(sim: dict, table_path, figure_paths: dict | None = None, inputs=()) -> pd.DataFrame:
    from ..report.tables import write_table
    from ..sim import figures

    figure_paths = figure_paths or {k: Path(table_path).parents[1] / "figures" / v
                                    for k, v in STABILITY_FIGURES.items()}
    with _open_run("stability", sim, inputs) as handle:
        table, analyses, logs = stability_study(sim, _Run("stability", handle))
        write_table(table, table_path, title="Stability with a_b-input force models (eqs. 5.13-5.16)")
        figures.eigenvalue_figure(analyses, figure_paths["eigenvalues"])
        figures.divergence_figure(logs, figure_paths["divergence"], settings(sim).limits.max_accel_g)
        for p in [table_path, *figure_paths.values()]:
            handle.artifact(p)
    return table


def run(sim: dict, results_dir, task: str = "all") -> None:
    out = Path(results_dir)
    if task not in ("all", "tracking", "stability"):
        raise QrInputError("simulate.task", f"unknown task {task!r}", "use all, tracking or stability")
    if task in ("all", "tracking"):
        write_tracking(sim, out / "simulation" / "tracking.csv",
                       {k: out / "figures" / v for k, v in FIGURES.items()})
    if task in ("all", "stability"):
        write_stability(sim, out / "simulation" / "stability.csv",
                        {k: out / "figures" / v for k, v in STABILITY_FIGURES.items()})


def simulate_config(overrides=()) -> dict:
    """The resolved ``sim`` group (Hydra compose with overrides, e.g. ``['simulate=thesis']``)."""
    from ..config import compose, to_dict

    return to_dict(compose(overrides))["simulate"]


def _main(cfg) -> None:
    from ..config import to_dict

    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    c = to_dict(cfg)
    run(c["simulate"], c["results"], c["simulate"].get("task", "all"))


def main() -> None:
    """``qr simulate`` / ``qr simulate``."""
    from ..config import hydra_app

    hydra_app("simulate", _main)


if __name__ == "__main__":
    main()
