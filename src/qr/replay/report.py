"""``qr replay``'s report: the answer in one sentence, the tables, the setpoints found, what is not modelled,
and one figure per flight.  Every sentence is built from the numbers of ``replay.json`` it states
(tests/replay/test_replay_report.py reads them back); the figures from the :class:`Replay`'s samples."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

FIGURE_CAPTION = ("Flight {name}: the logged path (black) and each vehicle file flown in closed loop under the "
                  "{controller} controller along the rebuilt setpoints (dashed grey: the setpoint). Left: x–y (m); "
                  "middle: height against time (s); right: the rotor speeds ({unit}) against time, logged (black) "
                  "and simulated, one panel per rotor. Where a coloured curve leaves the black one, that model "
                  "parts from the flight.")


def _f(x, fmt="{:.3g}", none="–"):
    return none if x is None else fmt.format(x)


def _best(doc: dict, key: tuple) -> str | None:
    have = {v: m[key[0]][key[1]] for v, m in doc["models"].items() if m[key[0]][key[1]] is not None}
    return min(have, key=have.get) if have else None


def headline(doc: dict) -> str:
    """The answer: which model flies closest to the logs, by how much, and where the simulation parts."""
    lab = doc["labels"]
    models = doc["models"]
    n = len(doc["flights"])
    best = _best(doc, ("position", "rmse_m"))
    ctrl = doc["controller"]["name"]
    if best is None:
        return f"No vehicle file could be compared with the {n} flight(s): no sample had both a logged and a simulated pose."
    b = models[best]
    s = (f"Flown in closed loop under the {ctrl} controller along the rebuilt setpoints of {n} flight"
         f"{'s' if n > 1 else ''}, {lab[best]} flies closest to the log: position RMSE "
         f"{_f(b['position']['rmse_m'])} m (max {_f(b['position']['max_m'])} m), attitude "
         f"{_f(b['attitude']['rmse_deg'])}°, rotor speeds {_f(b['rotor_speed']['rmse_percent'])} % RMS")
    others = [v for v in models if v != best]
    if others:
        s += "; " + "; ".join(f"{lab[v]} {_f(models[v]['position']['rmse_m'])} m, {_f(models[v]['attitude']['rmse_deg'])}°, "
                              f"{_f(models[v]['rotor_speed']['rmse_percent'])} %" for v in others)
    parts = b["position"]["parts_at_s"]
    thr = doc["config"]["replay"]["part_position_m"]
    if parts is None:
        s += f". {lab[best]} stays within {thr:g} m of the logged path throughout"
    else:
        s += f". {lab[best]} parts from the logged path (more than {thr:g} m) {parts:.2f} s after the replay's start"
    lost = [lab[v] for v in models if models[v]["diverged_at_s"] is not None]
    if lost:
        s += f"; lost in flight (stopped): {', '.join(lost)}"
    return s + "."


def _table(doc: dict, models: dict) -> list[str]:
    lab = doc["labels"]
    unit = next(iter(models.values()))["rotor_speed"]["unit"]
    kind = next(iter(models.values()))["thrust"]["kind"]
    lines = [f"| model | position RMSE (m) | max (m) | parts at (s) | attitude RMSE (°) | max (°) | rotor speeds RMSE "
             f"({unit}) | (% of mean) | thrust RMSE (N, {kind}) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for v, m in models.items():
        lines.append(f"| {lab.get(v, v)} | {_f(m['position']['rmse_m'])} | {_f(m['position']['max_m'])} | "
                     f"{_f(m['position']['parts_at_s'], '{:.2f}', 'never')} | {_f(m['attitude']['rmse_deg'])} | "
                     f"{_f(m['attitude']['max_deg'])} | {_f(m['rotor_speed']['rmse'], '{:.4g}')} | "
                     f"{_f(m['rotor_speed']['rmse_percent'])} | {_f(m['thrust']['rmse_N'])} |")
    return lines


def _setpoints_table(doc: dict) -> list[str]:
    lines = ["| flight | trajectory | time scale | start (s) | ± (s) | start point (m) | controller mass (kg) | found from |",
             "|---|---|---:|---:|---:|---|---:|---|"]
    for f, s in doc["setpoints"].items():
        lines.append(f"| {Path(f).name} | {Path(s['trajectory']).name} | {s['timescale']:g} | {s['offset_s']:.4f} | "
                     f"{_f(s['offset_uncertainty_s'], '{:.4f}')} | "
                     f"[{', '.join(f'{x:.3f}' for x in s['origin_m'])}] | {s['controller_mass_kg']:.4g} "
                     f"({s['controller_mass_source']}) | {s['source']} |")
    return lines


def figure_name(flight: str, i: int) -> str:
    return f"figures/{i:02d}_{re.sub(r'[^A-Za-z0-9_.-]+', '_', Path(flight).name)}.png"


def report(doc: dict, figures: dict | None = None) -> str:
    """report.md of a ``replay.json`` document; ``figures``: flight -> the figure's path relative to it."""
    out = ["# qr replay", "", headline(doc), "",
           f"Controller: {doc['controller']['name']} at {doc['controller']['rate_hz']:g} Hz; mixer: "
           f"{doc['mixer']['kind']}. Errors at the log's pose stamps; the position is the tracked point's.", "",
           "## All flights", "", *_table(doc, doc["models"]), ""]
    if len(doc["flights"]) > 1:
        out += ["## Per flight", ""]
        for f, block in doc["per_flight"].items():
            out += [f"### {Path(f).name} ({block['duration_s']:.1f} s)", "", *_table(doc, block["models"]), ""]
    out += ["## Setpoints", "",
            "The trajectory each flight tracked, flown relative to its start point; the start time on the log's "
            "clock, the start point and the controller's mass parameter as found (± half the difference between "
            "the start times of the flight's two halves).", "", *_setpoints_table(doc), "",
            "## What the replay does not model", "", *[f"- {u}" for u in doc["unknown"]], ""]
    if figures:
        out += ["## Figures", ""]
        ctrl, unit = doc["controller"]["name"], next(iter(doc["models"].values()))["rotor_speed"]["unit"]
        for f, path in figures.items():
            out += [f"![{Path(f).name}]({path})", "",
                    "*" + FIGURE_CAPTION.format(name=Path(f).name, controller=ctrl, unit=unit) + "*", ""]
    return "\n".join(out)


def flight_figure(flight, controller: str, unit: str, path) -> None:
    """One flight: x–y path, height against time, rotor speeds against time; logged and each model."""
    from ..report.figures import save, subplots

    t = flight.t - flight.setup.window[0]
    fig = subplots(figsize=(13, 4.2))[0]
    fig.clf()
    gs = fig.add_gridspec(4, 3, width_ratios=[1.1, 1.3, 1.6], hspace=0.35, wspace=0.3)
    axy = fig.add_subplot(gs[:, 0])
    az = fig.add_subplot(gs[:, 1])
    au = [fig.add_subplot(gs[i, 2]) for i in range(4)]
    sp = flight.setup.setpoints.at(flight.t, order=0)["p"]
    lp = flight.logged.p
    axy.plot(sp[:, 0], sp[:, 1], color="0.6", ls="--", lw=1, label="setpoint")
    axy.plot(lp[:, 0], lp[:, 1], color="k", lw=1.4, label="logged")
    az.plot(t, sp[:, 2], color="0.6", ls="--", lw=1)
    az.plot(t, lp[:, 2], color="k", lw=1.4)
    for i in range(4):
        au[i].plot(t, flight.logged.u[:, i], color="k", lw=1.0)
    for k, m in enumerate(flight.models):
        c = f"C{k}"
        axy.plot(m.p[:, 0], m.p[:, 1], color=c, lw=1.1, label=m.label)
        az.plot(t, m.p[:, 2], color=c, lw=1.1)
        for i in range(4):
            au[i].plot(t, m.u[:, i], color=c, lw=0.9)
    axy.set_xlabel("x (m)")
    axy.set_ylabel("y (m)")
    axy.set_aspect("equal", adjustable="datalim")
    axy.legend(fontsize=7, loc="best")
    az.set_xlabel("time since the replay's start (s)")
    az.set_ylabel("height z (m)")
    for i in range(4):
        au[i].set_ylabel(f"u{i + 1} ({unit})", fontsize=7)
        au[i].tick_params(labelsize=7)
        if i < 3:
            au[i].set_xticklabels([])
    au[3].set_xlabel("time since the replay's start (s)")
    fig.suptitle(f"{flight.name}: logged and replayed under {controller}", fontsize=10)
    save(fig, path, tight=True)


def figures(replay, folder: Path) -> dict:
    """Draw every flight's figure into ``folder`` (the output's root); flight path -> relative path."""
    out = {}
    (folder / "figures").mkdir(exist_ok=True)
    for i, f in enumerate(replay.flights):
        rel = figure_name(f.path, i)
        flight_figure(f, replay.controller.name, replay.rotor_unit, folder / rel)
        out[f.path] = rel
    return out


def metrics(doc: dict) -> dict:
    """MLflow metrics per vehicle label: ``<label>.position_rmse_m`` and friends."""
    out = {}
    for v, m in doc["models"].items():
        name = re.sub(r"[^A-Za-z0-9_\-./:]+", "_", doc["labels"].get(v, v)).strip("_")
        for key, val in (("position_rmse_m", m["position"]["rmse_m"]), ("attitude_rmse_deg", m["attitude"]["rmse_deg"]),
                         ("rotor_rmse_percent", m["rotor_speed"]["rmse_percent"]), ("thrust_rmse_N", m["thrust"]["rmse_N"])):
            if val is not None and np.isfinite(val):
                out[f"{name}.{key}"] = float(val)
    return out
