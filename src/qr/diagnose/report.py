"""``report.md`` and its figures, drawn from a :class:`qr.diagnose.Diagnosis`.

Every number a sentence states is the one ``diagnosis.json`` states (:func:`qr.diagnose.document.stated`);
the tables of RMSE and anatomy print the diagnosis's own numbers to their own digits.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.ticker import MaxNLocator

from ..atomic import write_text
from ..effects import CATALOG, with_unit
from ..report import figures
from ..report.background import BackgroundFigure
from ..rollout import table
from ..rotors import SPEED_UNIT_NAMES
from .accelerometer import statement as accelerometer_statement
from .core import AXES
from .diagnosis import Diagnosis
from .replay import Replays
from .document import stated
from .wind import WIND


def _slow_torque_lines(slow: dict | None) -> list[str]:
    if not slow or not slow.get("axes"):
        return []
    parts = []
    for a in slow["axes"]:
        if "estimate" not in a:
            parts.append(f"{a['parameter']}: {a['why_not']}")
            continue
        head = f"{a['parameter']} = {a['estimate']:.3g} ± {a['stderr']:.2g} kg m²"
        parts.append(head + (f" ({100 * a['cv_gain']:.1f} % of the summed {a['axis']} residual), named" if a["named"]
                             else f": not named, it {a['why_not']} on {a['axis']}"))
    note = f" ({slow['note']})" if slow.get("note") else ""
    return [f"Slow torque balance (each inertia entry judged on its axis's torque residual summed over "
            f"{slow['horizon']} samples, after the named effects): " + "; ".join(parts) + f".{note}\n"]


def _anatomy_table(anatomy: dict) -> list[str]:
    """The residual-anatomy table; "–" for an axis at the noise floor (its share is NaN or None)."""
    if not anatomy:
        return []
    shares = {k: np.array([np.nan if x is None else x for x in v], dtype=float) for k, v in anatomy.items()}
    floor = np.all([~np.isfinite(v) for v in shares.values()], axis=0)
    if floor.all():
        return ["Residual anatomy: every axis's held-out residual is at the noise floor; there is nothing above "
                "noise for a candidate to explain.\n"]
    L = ["Residual anatomy: share of each axis's held-out residual (above the noise floor) that each candidate "
         "explains on its own, fitted on the training part (1 = all of it, < 0 = worse than nothing; shares of "
         "different candidates overlap; – = the axis is at the noise floor, nothing to share out):\n",
         "| candidate | " + " | ".join(AXES) + " |", "|---|" + "---:|" * 6]
    best = {k: (np.nanmax(v) if np.isfinite(v).any() else -np.inf) for k, v in shares.items()}
    for name in sorted(shares, key=lambda k: -best[k]):
        cells = " | ".join("–" if not np.isfinite(x) else "0" if abs(x) < 0.005 else f"{x:.2f}"
                           for x in shares[name])
        L.append(f"| `{name}` | {cells} |")
    return L + [""]


def _conventions(per_flight: list[dict]) -> list[str]:
    """The convention checks (qr.conventions): what each measured, or that every flight passed them."""
    if not per_flight:
        return []
    done = sorted({c["check"] for f in per_flight for c in f["checks"]})
    if len(per_flight) > 3:
        return [f"Conventions: all {len(per_flight)} flights pass the {', '.join(done)} checks "
                "(frames, quaternion order, units, rotor numbering; diagnosis.json says what each measured).\n"]
    out = ["Conventions (frames, quaternion order, units, rotor numbering), checked before any identification:\n"]
    for f in per_flight:
        out += [f"- {Path(f['flight']).name}, {c['check']}: {c['measured']}." for c in f["checks"]]
    return out + [""]


def _opening(doc: dict) -> list[str]:
    names = doc["flights"]
    title = ", ".join(names) if len(names) <= 3 else f"{len(names)} flights ({names[0]} ... {names[-1]})"
    cfg, split = doc["config"], doc["split"]
    return [f"# Diagnosis: {title}\n", f"**{doc['verdict']}**\n",
            f"{doc['samples']} samples. The first {100 * cfg['train_fraction']:.0f} % of each flight trains, "
            f"the rest is held out after a {cfg['gap_s']:g} s gap (first flight: trained on "
            f"{split['train'][0]:.1f}-{split['train'][1]:.1f} s, tested on "
            f"{split['test'][0]:.1f}-{split['test'][1]:.1f} s); all numbers below are on the held-out part.\n"]


def _how_far(d: Diagnosis) -> list[str]:
    h = d.held_out
    L = ["## How far the nominal model is off\n", "| axis | nominal RMSE | extended RMSE | noise floor | extended / noise |",
         "|---|---:|---:|---:|---:|"]
    for i, a in enumerate(AXES):
        unit = "N" if i < 3 else "N m"
        n, e, f = h.nominal_rmse[i], h.extended_rmse[i], h.noise_floor_rmse[i]
        L.append(f"| {a} ({unit}) | {n:.4g} | {e:.4g} | {f:.4g} | {e / f:.2f} |")
    return L + [""]


def _named_causes(d: Diagnosis, doc: dict, vehicle=None) -> list[str]:
    L = ["## Named causes\n"]
    if doc["effects"]:
        L += ["| effect | parameters (± block-bootstrap s.e.) | explained fraction | confounded with |",
              "|---|---|---:|---|"]
        for e in doc["effects"]:
            par = ", ".join(f"{k} = {v:.4g} ± " + with_unit(e["name"], k, e["stderr"].get(k, float("nan")), ".2g", vehicle)
                            for k, v in e["parameters"].items())
            L.append(f"| `{e['name']}` | {par} | {e['explained_fraction']:.3f} | "
                     f"{', '.join(e['confounded_with']) or '-'} |")
        L.append("")
        if d.held_out.misfit:
            L.append("The model does not describe this flight (above): its largest effect is stated, fitted alone, "
                     "with its share of the held-out residual alone; nothing else is named, and extended_vehicle.yaml "
                     "is the vehicle as given.\n")
        windy = {m.effect: m for m in d.fit.wind}
        for e in doc["effects"]:
            L.append(f"- `{e['name']}`: {CATALOG[e['name']].doc}.")
            others = [c for c in e["confounded_with"] if not (c == WIND and e["name"] in windy)]
            if others:
                L.append(f"  On this flight it cannot be told apart from {', '.join(others)}; "
                         "the simpler one is named.")
            if e["name"] in windy:
                said = windy[e["name"]].sentence()
                L.append(f"  On this flight {said}.")
        L.append("")
    elif d.held_out.misfit:
        L.append("None: the model does not describe this flight (above).\n")
    elif d.not_named:
        L.append("None: what the selection found on the training part is not supported by the held-out part "
                 "(below).\n")
    else:
        L.append("None: no catalog effect improves the cross-validated fit by more than "
                 f"{100 * doc['config']['selection']['min_gain']:.0f} % of the residual.\n")
    if d.not_named:
        L += ["Selected on the training part, but not named:\n", *(f"- `{e}`: {why}." for e, why in d.not_named.items()),
              ""]
    return L


def _vehicle_file(doc: dict) -> list[str]:
    if not (doc["vehicle_file"] or doc["vehicle_file_unresolved"]):
        return []
    return ["## The vehicle file\n", *(f"- {c['statement'][0].upper() + c['statement'][1:]}." for c in doc["vehicle_file"]),
            *(f"- {c['why']}." for c in doc["vehicle_file_unresolved"]), ""]


def _path_row(s: dict) -> str:
    best = ", ".join(f"`{e}`" for e in s["effects"]) or "(nominal)"
    runner = (", ".join(s["runner_up"]) + f" ({s['runner_up_loss']:.4g})") if s.get("runner_up") else "-"
    gain = f"{100 * s['gain']:.1f} %" if s["size"] else "-"
    share = f"{100 * s['fold_share']:.0f} %" if s["size"] else "-"
    med = f"{s['t']:.1f}" if s["size"] else "-"
    edge = "-" if "margin" not in s else (f"on the edge ({s['margin']:.1e}: {', '.join(s['on_edge'])})"
                                         if s["on_edge"] else f"{s['margin']:+.2g}")
    return (f"| {s['size']} | {best} | {s['loss']:.4g} | {gain} | {share} | {med} | {runner} | "
            f"{'yes' if s['accepted'] else 'no'} | {edge} |")


def _selection(doc: dict) -> list[str]:
    sel, c = doc["selection"], doc["config"]["selection"]
    L = ["Selection path: the best set of each size by cross-validated loss (noise-variance units); a "
         "larger set is named only if it beats the smaller one by "
         f"{100 * c['min_gain']:.0f} % in most folds, or by {100 * c['strong_gain']:.0f} % where it acts (paired "
         f"per-block t >= {c['t_gain']:g}). The closest margin is the decision's statistic against "
         "its nearest threshold (relative); within 1e-9 it is numerical noise, decided against the larger "
         "set on every machine (\"on the edge\"):\n",
         "| effects | best set | CV loss | gain | folds improved | paired t | runner-up (loss) | named | "
         "closest margin |", "|---:|---|---:|---:|---:|---:|---|---|---:|", *map(_path_row, sel["path"]), ""]
    if sel["equivalent"]:
        L.append("Sets the data cannot tell from the named one (the simplest is named):\n")
        L += [f"- {', '.join(f'`{x}`' for x in e['effects'])}: CV loss {e['loss']:.4g} (paired t {e['t']:.2f})"
              for e in sel["equivalent"]]
        L.append("")
    return L


def _arbitration(doc: dict) -> list[str]:
    L = []
    for name, a in doc["selection"]["torque_arbitration"].items():
        given = ", ".join(f"`{e}`" for e in a.get("given", [])) or "no other effect"
        L.append(f"Roll/pitch torque cannot arbitrate `{name}`: given {given}, the torque rows would need "
                 f"{a['torque_rows'][0]:.3g} (the force rows alone {a['force_rows'][0]:.3g}), beyond any plausible "
                 "C_T error: the measured roll/pitch torque is not the rotor map's (inertia, latency or smoothing "
                 f"of the attitude channel).  `{name}` is fitted on the force rows, where it is the same term as "
                 "`mass_error` (reported as confounded).\n")
    return L


def _rejected(doc: dict) -> list[str]:
    rejected = doc["selection"]["rejected"]
    if not rejected:
        return []
    return ["Candidates not named on this data (unphysical, self-contradicting, or collinear with a "
            "named effect):\n", *(f"- `{name}`: {why}." for name, why in rejected.items()), ""]


def _beyond(d: Diagnosis) -> list[str]:
    return ["## Beyond the catalog\n", d.remainder.statement, ""]


def _replay(doc: dict) -> list[str]:
    r = doc["replay"]
    L = [f"## Open-loop replay (restarted every {r['horizon_s']:g} s, driven by the measured rotor speeds)\n",
         "| model | position RMSE at horizon (m) | x | y | z | attitude (deg) |", "|---|---:|---:|---:|---:|---:|"]
    for k in ("nominal", "extended"):
        ax = r[f"{k}_position_rmse_axes"] or [float("nan")] * 3
        L.append(f"| {k} | {r[f'{k}_position_rmse']:.4g} | {ax[0]:.3g} | {ax[1]:.3g} | {ax[2]:.3g} | "
                 f"{r[f'{k}_attitude_rmse_deg']:.3g} |")
    return L + [""]


def _rollout(d: Diagnosis) -> list[str]:
    ro = d.rollout
    if not ro.models:
        return []
    L = [f"## Multi-step rollout (held-out part, every start, H = {ro.horizon} steps; `qr evaluate`)\n",
         "Mean absolute error at step h: p (m), v (m/s), R (rad), w (rad/s); `hold` holds the state, "
         "`rate_frozen` is the benchmark's physics baseline (nominal thrust, no drag, body rate held).\n",
         *table(ro.models, ro.horizon), ""]
    ex = ro.explained
    fmt = lambda x: "–" if x is None or x != x else f"{100 * x:.0f} %"  # noqa: E731
    return L + [f"Share of the held-out residual the named effects explain, sample by sample and summed "
                f"over {ex.horizon} samples (the slow error a rollout integrates):\n",
                "| | " + " | ".join(AXES) + " |", "|---|" + "---:|" * len(AXES),
                "| one step | " + " | ".join(fmt(x) for x in ex.one_step) + " |",
                f"| summed over {ex.horizon} | " + " | ".join(fmt(x) for x in ex.summed) + " |", ""]


def _torque_remainder(doc: dict) -> list[str]:
    rem = doc.get("torque_remainder")
    if not rem:
        return []
    return ["## Learned torque remainder (a hybrid, not a cause)\n",
            f"A linear map of {rem['features']} (ridge {rem['ridge']:g}), fitted on the training part to the "
            "torque the named effects leave, is written into `extended_vehicle.yaml` (`torque_remainder`) and "
            "rolled out as `hybrid` above. Held-out torque RMSE x / y / z (N m): extended "
            + " / ".join(f"{x:.2e}" for x in rem["extended_torque_rmse"]) + ", hybrid "
            + " / ".join(f"{x:.2e}" for x in rem["hybrid_torque_rmse"]) + ".\n"]


def _closing(d: Diagnosis, figs: dict) -> list[str]:
    L = ["## The force label against the accelerometer\n", accelerometer_statement(d.accelerometer) + "\n"] \
        if d.accelerometer else []
    L.append("## Figures\n")
    L += [f"### {title}\n\n![{title}](figures/{name})\n" for title, name in figs.items()]
    if not d.described:
        return L + ["## Extended model\n", "`extended_vehicle.yaml`: the vehicle as given, nothing added (the model "
                    "does not describe this flight; what it identifies is in diagnosis.json's effects).\n"]
    return L + ["## Extended model\n",
                "`extended_vehicle.yaml`: the nominal vehicle plus the named effects; `qr synth`, the replay and the "
                "simulation study accept it.\n"]


def _refinement(doc: dict) -> list[str]:
    """The refinement by simulation error (``diagnose.refine=rollout``), beside the one-step estimates."""
    if not doc.get("refine"):
        return []
    from .refine import report_lines

    return report_lines(doc["refine"])


def write_report(outdir: Path, d: Diagnosis, figs: dict, vehicle=None) -> None:
    """``outdir/report.md``: the answer first, then how far the nominal model is off, what is named and
    why, the vehicle file, the selection's evidence, replay, rollout, and the figures ``figs`` (title ->
    file name under ``figures/``); ``vehicle``: its rotor-speed unit in the parameters' units."""
    doc = stated(d)
    L = [*_opening(doc), *_data_used(doc), *_conventions(doc["conventions"]), *_how_far(d),
         *_named_causes(d, doc, vehicle), *_vehicle_file(doc), *_selection(doc), *_anatomy_table(d.held_out.anatomy),
         *_arbitration(doc), *_slow_torque_lines(doc["selection"]["slow_torque"]), *_rejected(doc), *_beyond(d),
         *_replay(doc), *_rollout(d), *_torque_remainder(doc), *_refinement(doc), *_closing(d, figs)]
    write_text(outdir / "report.md", "\n".join(L) + "\n")


def _data_used(doc: dict) -> list[str]:
    """Report lines on the rows left out: ground time, time gaps, unused segments (only when there are any)."""
    L = []
    for a in doc.get("airborne", []):
        if a["dropped_s"] > 0:
            L.append(f"- `{a['flight']}`: airborne {a['window'][0]:.2f}-{a['window'][1]:.2f} s; "
                     f"{a['dropped_s']:.1f} s on the ground left out (motors off or idling, or at rest).")
    for g in doc.get("time_gaps", []):
        L.append(f"- `{g['flight']}`: no samples from {g['from']:.2f} to {g['to']:.2f} s; the parts before and "
                 "after are filtered, replayed and cut into blocks separately.")
    for s in doc.get("segments", []):
        if not s["used"]:
            L.append(f"- `{s['flight']}`: segment {s['window'][0]:.2f}-{s['window'][1]:.2f} s not used: {s['note']}.")
    return (["Data used (times in each flight's own clock):\n", *L, ""]) if L else []


def make_figures(outdir: Path, d: Diagnosis, vehicle, anatomy=None) -> dict:
    """The report's figures into ``outdir/figures``: title -> file name; ``anatomy``: a
    :class:`BackgroundFigure` already drawing the residual anatomy."""
    figdir = outdir / "figures"
    figdir.mkdir(exist_ok=True)
    out = {}
    # the two figures side by side: the residual's in a forked child (qr.report.background), the replay's here
    residual = BackgroundFigure(lambda path: residual_figure(d, path))
    try:
        replay_figure(d.replay, figdir / "replay_drift.png")
    finally:
        residual.collect(figdir / "residual_vs_effects.png")
    out["Held-out residual force and torque of the nominal model (grey; flights one after another, shaded "
        "alternately) and what the named effects explain (red): where red follows grey, a named effect "
        "accounts for it"] = "residual_vs_effects.png"
    out["Open-loop replay: drift of the nominal and extended models"] = "replay_drift.png"
    if anatomy is None:
        anatomy_figure(d.labels.full, vehicle, figdir / "residual_anatomy.png")
    else:
        anatomy.collect(figdir / "residual_anatomy.png")
    out["Residual anatomy: nominal residual against body velocity, height, thrust and the rotor speeds "
        "(binned means, one colour per rotor)"] = \
        "residual_anatomy.png"
    return out


def residual_figure(d: Diagnosis, path: Path) -> None:
    """The held-out residual of the nominal model and the named effects' terms, flights (segments) one
    after another on the axis, never joined across flights or time gaps."""
    prep = d.labels.full
    test = prep.test
    step = max(1, int(test.sum()) // 20000)
    x, (y, pred), spans = figures.end_to_end(prep.t[test][::step], prep.flight[test][::step], prep.y[test][::step],
                                             d.held_out.prediction[::step])
    fig, axs = figures.subplots(6, 1, figsize=(8, 9), sharex=True)
    for i, ax in enumerate(axs):
        for a, b in spans[1::2]:
            ax.axvspan(a, b, color="0.93", lw=0)
        ax.plot(x, y[:, i], lw=0.6, color="grey", label="residual (nominal model)")
        ax.plot(x, pred[:, i], lw=0.9, color="C3", label="named effects")
        ax.set_ylabel(AXES[i] + (" (N)" if i < 3 else " (N m)"))
    axs[0].legend(fontsize=7, loc="upper right")
    axs[-1].set_xlabel("t (s), held-out part" if len(spans) == 1 else
                       f"held-out time (s) of {len(spans)} flights or segments, one after another (shaded alternately)")
    figures.save(fig, path)


def replay_figure(replay: Replays, path: Path) -> None:
    """The replay's error growth per axis, and the three worst windows."""
    fig, axs = figures.subplots(1, 2, figsize=(9, 3.2))
    for key, c in (("nominal", "grey"), ("extended", "C3")):
        g = getattr(replay, key).growth
        for j, a in enumerate("xyz"):
            axs[0].plot(g["elapsed"], g[f"e{a}"], color=c, ls=["-", "--", ":"][j], label=f"{key} {a}")
    axs[0].set_xlabel("time since restart (s)")
    axs[0].set_ylabel("RMS position error (m)")
    axs[0].legend(fontsize=6, ncol=2)
    err = replay.nominal.errors
    err = err[np.isfinite(err["ex"])]
    last = err.groupby("window").tail(1)
    worst = last.assign(e=np.sqrt(last.ex**2 + last.ey**2 + last.ez**2)).nlargest(3, "e")["window"]
    for k, wdw in enumerate(worst):
        for key, c in (("nominal", "grey"), ("extended", "C3")):
            e = getattr(replay, key).errors
            e = e[e["window"] == wdw]
            axs[1].plot(e["elapsed"], np.sqrt(e.ex**2 + e.ey**2 + e.ez**2), color=c, lw=1,
                        label=key if k == 0 else None)
    axs[1].set_xlabel("time since restart (s)")
    axs[1].set_ylabel("position error (m)")
    axs[1].set_title("three worst windows", fontsize=8)
    axs[1].legend(fontsize=7)
    figures.save(fig, path)


def anatomy_figure(prep, vehicle, path: Path) -> None:
    """The nominal residual against the regressors of the catalog's effects (binned means): needs the
    prepared data only, so it can be drawn while the selection runs (:class:`BackgroundFigure`)."""
    # at most 20000 points per panel: a scatter of a 1-hour log would take minutes to draw
    step = max(1, len(prep.t) // 20000)
    s = prep.s.take(slice(None, None, step))
    y_all = prep.y[::step]
    T, _ = vehicle.rotors.thrust_torque(s.u)
    regs = {"v_bx (m/s)": s.v_b[:, 0], "v_by (m/s)": s.v_b[:, 1], "v_bz (m/s)": s.v_b[:, 2],
            "height (m)": s.p[:, 2] - vehicle.ground_z, "thrust T (N)": T,
            # the rotors share a panel: a weak one stands out by its colour
            f"rotor speed u1..u4 ({SPEED_UNIT_NAMES.get(vehicle.rotor_speed_unit, vehicle.rotor_speed_unit)})": s.u}
    # no grid: a scatter needs none, and 36 panels' grid lines are much of the drawing time
    fig, axs = figures.subplots(6, len(regs), figsize=(2.0 * len(regs), 9), sharex="col", sharey="row",
                                grid=False)
    fig.subplots_adjust(left=0.06, right=0.99, bottom=0.06, top=0.99, wspace=0.08, hspace=0.08)
    for j, (name, x) in enumerate(regs.items()):
        for i in range(6):
            ax = axs[i, j]
            if x.ndim == 1:
                ax.plot(x, y_all[:, i], ",", alpha=0.3, color="grey")
                _binned(ax, x, y_all[:, i])
            else:
                ax.plot(x.ravel(), np.repeat(y_all[:, i], x.shape[1]), ",", alpha=0.15, color="grey")
                for r in range(x.shape[1]):
                    _binned(ax, x[:, r], y_all[:, i], color=f"C{r}", label=f"u{r + 1}")
                if i == 0:
                    ax.legend(fontsize=6, loc="upper left", ncol=2)
            if j == 0:
                ax.set_ylabel(AXES[i] + (" (N)" if i < 3 else " (N m)"), fontsize=7)
                ax.yaxis.set_major_locator(MaxNLocator(4))
            if i == 5:
                ax.set_xlabel(name, fontsize=7)
            ax.xaxis.set_major_locator(MaxNLocator(3))  # few ticks: the panels' tick layout is most of the cost
            ax.tick_params(labelsize=6)
    figures.save(fig, path, tight=False)


def _binned(ax, x, y, bins=15, color="C3", label=None):
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < bins * 5:
        return
    edges = np.quantile(x[ok], np.linspace(0, 1, bins + 1))
    idx = np.clip(np.digitize(x[ok], edges) - 1, 0, bins - 1)
    mx = np.array([x[ok][idx == b].mean() for b in range(bins)])
    my = np.array([y[ok][idx == b].mean() for b in range(bins)])
    ax.plot(mx, my, color=color, lw=1.2, label=label)
