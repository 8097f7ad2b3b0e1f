"""``diagnosis.json`` (the machine contract of docs/spec/diagnosis.md) and ``report.md``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.ticker import MaxNLocator

from ..effects import CATALOG
from ..report import figures
from .core import AXES

SCHEMA = "qr.diagnosis/1"


def _r(x, n=6):
    return [float(f"{v:.{n}g}") for v in x]


def to_json(res: dict, flight_names: list[str], cfg_dict: dict) -> dict:
    rep_n, rep_e = res["replay"]["nominal"]["summary"], res["replay"]["extended"]["summary"]
    effects = [{
        "name": e["name"],
        "parameters": {k: float(f"{v:.6g}") for k, v in e["parameters"].items()},
        "stderr": {k: float(f"{v:.3g}") for k, v in e["stderr"].items()},
        "explained_fraction": float(f"{e['explained_fraction']:.4g}"),
        "confounded_with": list(e["confounded_with"]),
    } for e in res["effects"]]
    w0 = res["windows"][0]
    ms = lambda w: [round(float(x), 3) for x in w]  # noqa: E731  (on the file's t axis, which may be a clock)
    return {
        "schema": SCHEMA,
        "flights": flight_names,
        "samples": res["samples"],
        "split": {"train": ms(w0["train"]), "test": ms(w0["test"]),
                  "per_flight": [{"train": ms(w["train"]), "test": ms(w["test"])} for w in res["windows"]]},
        "nominal": {"force_rmse": _r(res["nominal_rmse"][:3]), "torque_rmse": _r(res["nominal_rmse"][3:])},
        "effects": effects,
        "extended": {"force_rmse": _r(res["extended_rmse"][:3]), "torque_rmse": _r(res["extended_rmse"][3:])},
        "replay": {
            "horizon_s": float(cfg_dict["horizon_s"]),
            "nominal_position_rmse": float(f"{rep_n.get('position_rmse', float('nan')):.6g}"),
            "extended_position_rmse": float(f"{rep_e.get('position_rmse', float('nan')):.6g}"),
            "nominal_position_rmse_axes": _r(rep_n.get("position_rmse_axes", [])),
            "extended_position_rmse_axes": _r(rep_e.get("position_rmse_axes", [])),
            "nominal_attitude_rmse_deg": float(f"{rep_n.get('attitude_rmse_deg', float('nan')):.4g}"),
            "extended_attitude_rmse_deg": float(f"{rep_e.get('attitude_rmse_deg', float('nan')):.4g}"),
            "windows": rep_n.get("windows", 0),
        },
        "rollout": res.get("rollout", {}),
        "noise_floor": {"force_rmse": _r(res["noise_floor_rmse"][:3]), "torque_rmse": _r(res["noise_floor_rmse"][3:]),
                        "source": res.get("noise_source", "filter covariance")},
        "remainder": res.get("remainder", {}),
        "anatomy": {k: _r(v, 4) for k, v in res.get("anatomy", {}).items()},
        "selection": {"cv_loss_nominal": float(f"{res['selection']['cv_loss_nominal']:.6g}"),
                      "cv_loss_final": float(f"{res['selection']['cv_loss_final']:.6g}"),
                      "path": [_clean(s) for s in res["selection"]["path"]],
                      "equivalent": [_clean(s) for s in res["selection"].get("equivalent", [])],
                      "rejected": res["selection"].get("rejected", {}),
                      "not_named": res["selection"].get("not_named", {}),
                      "torque_arbitration": {k: {r: (_r(v, 4) if r != "given" else v) for r, v in d.items()}
                                             for k, d in res.get("torque_arbitration", {}).items()},
                      "slow_torque": _slow_json(res.get("slow_torque"))},
        "verdict": verdict(res),
        "described": not res.get("misfit"),
        **({"misfit": {k: float(f"{v:.4g}") for k, v in res["misfit"].items()}} if res.get("misfit") else {}),
        "config": cfg_dict,
    }


def _slow_json(slow: dict | None) -> dict | None:
    if not slow:
        return None
    axes = [{k: (float(f"{v:.4g}") if isinstance(v, float) else v) for k, v in a.items()} for a in slow["axes"]]
    return {**slow, "axes": axes}


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
    return [f"Slow torque balance (each inertia entry judged on its axis's torque residual summed over "
            f"{slow['horizon']} samples, after the named effects): " + "; ".join(parts) + ".\n"]


def _clean(step: dict) -> dict:
    out = {}
    for k, v in step.items():
        if isinstance(v, float):
            out[k] = float(f"{v:.4g}")
        elif isinstance(v, dict):
            out[k] = {kk: float(f"{vv:.4g}") for kk, vv in list(v.items())[:6]}
        else:
            out[k] = v
    return out


def verdict(res: dict) -> str:
    ratio = res["nominal_loss"]
    misfit = res.get("misfit")
    if misfit:
        return (f"The model does not describe this flight: even extended, the held-out residual is "
                f"{100 * misfit['force_of_weight']:.0f} % of the weight in force and "
                f"{100 * misfit['torque_of_weight_at_arm']:.0f} % of the weight's torque at the arm "
                f"(a rigid-body model leaves under {100 * misfit['limit']:.0f} %), so nothing is named. Look at the "
                "log's frames and units (the convention checks in diagnosis.json), its time stamps and offsets "
                "(qr ingest prints them), the vehicle file (mass, thrust_coeff, rotor_speed_unit, layout) and "
                "events no model holds (ground contact, a tether, a crash).")
    if not res["effects"]:
        rem = res.get("remainder", {})
        tail = (f" An unexplained residual remains, correlated with {rem['correlated_with']}."
                if rem.get("structure_remains") else "")
        # "up to noise" only when the residual is at the noise floor's level (weighted loss ~ 1)
        fit = ("the nominal model explains this flight up to noise" if ratio < 2 else
               "no candidate effect explains the residual, which is well above noise")
        return (f"Nothing named: {fit} (weighted residual {ratio:.2f} x the noise floor's variance on "
                f"held-out data).{tail}")
    names = ", ".join(e["name"] for e in res["effects"])
    gain = 1 - res["extended_loss"] / res["nominal_loss"]
    return (f"Named {names}; the extended model removes {100 * gain:.0f} % of the nominal model's weighted "
            f"held-out residual variance (now {res['extended_loss']:.2f} x the noise floor's variance).")


def note_nulls(doc: dict) -> dict:
    """``doc`` as strict JSON: a number that is not finite becomes null, and ``notes`` says why."""
    from ..atomic import finite_or_null

    doc, nulls = finite_or_null(doc)
    notes = []
    if any(p.startswith("anatomy.") for p in nulls):
        notes.append("anatomy: null for an axis whose held-out residual is at the noise floor (nothing above "
                     "noise to share out)")
    held = [p for p in nulls if p.startswith("effects[") and ".stderr." in p]
    if held:
        notes.append(f"stderr null for a parameter held at the vehicle file's value, not estimated "
                     f"(selection.slow_torque says why): {', '.join(held)}")
    other = [p for p in nulls if not p.startswith("anatomy.") and p not in held]
    if other:
        notes.append(f"null where the number is not finite on this data (not computable): {', '.join(other)}")
    if notes:
        doc["notes"] = notes
    return doc


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


def write_report(outdir: Path, doc: dict, res: dict, figs: dict) -> None:
    L = []
    names = doc["flights"]
    title = ", ".join(names) if len(names) <= 3 else f"{len(names)} flights ({names[0]} ... {names[-1]})"
    L.append(f"# Diagnosis: {title}\n")
    L.append(f"**{doc['verdict']}**\n")
    L.append(f"{doc['samples']} samples. The first {100 * doc['config']['train_fraction']:.0f} % of each flight trains, "
             f"the rest is held out after a {doc['config']['gap_s']:g} s gap (first flight: trained on "
             f"{doc['split']['train'][0]:.1f}-{doc['split']['train'][1]:.1f} s, tested on "
             f"{doc['split']['test'][0]:.1f}-{doc['split']['test'][1]:.1f} s); all numbers below are on the "
             "held-out part.\n")
    L += _data_used(doc)
    L += _conventions(doc.get("conventions", []))
    L.append("## How far the nominal model is off\n")
    L.append("| axis | nominal RMSE | extended RMSE | noise floor | extended / noise |")
    L.append("|---|---:|---:|---:|---:|")
    for i, a in enumerate(AXES):
        unit = "N" if i < 3 else "N m"
        n, e, f = res["nominal_rmse"][i], res["extended_rmse"][i], res["noise_floor_rmse"][i]
        L.append(f"| {a} ({unit}) | {n:.4g} | {e:.4g} | {f:.4g} | {e / f:.2f} |")
    L.append("")
    L.append("## Named causes\n")
    if doc["effects"]:
        L.append("| effect | parameters (± block-bootstrap s.e.) | explained fraction | confounded with |")
        L.append("|---|---|---:|---|")
        for e in doc["effects"]:
            par = ", ".join(f"{k} = {v:.4g} ± {e['stderr'].get(k, float('nan')):.2g}" for k, v in e["parameters"].items())
            L.append(f"| `{e['name']}` | {par} | {e['explained_fraction']:.3f} | "
                     f"{', '.join(e['confounded_with']) or '-'} |")
        L.append("")
        for e in doc["effects"]:
            L.append(f"- `{e['name']}`: {CATALOG[e['name']].doc}.")
            if e["confounded_with"]:
                L.append(f"  On this flight it cannot be told apart from {', '.join(e['confounded_with'])}; "
                         "the simpler one is named.")
        L.append("")
    elif res.get("misfit"):
        L.append("None: the model does not describe this flight (above).\n")
    elif doc["selection"].get("not_named"):
        L.append("None: what the selection found on the training part is not supported by the held-out part "
                 "(below).\n")
    else:
        L.append("None: no catalog effect improves the cross-validated fit by more than "
                 f"{100 * doc['config']['selection']['min_gain']:.0f} % of the residual.\n")
    if doc["selection"].get("not_named"):
        L.append("Selected on the training part, but not named:\n")
        L += [f"- `{e}`: {why}." for e, why in doc["selection"]["not_named"].items()]
        L.append("")
    if doc.get("vehicle_file") or doc.get("vehicle_file_unresolved"):
        L.append("## The vehicle file\n")
        L += [f"- {c['statement'][0].upper() + c['statement'][1:]}." for c in doc.get("vehicle_file", [])]
        L += [f"- {c['why']}." for c in doc.get("vehicle_file_unresolved", [])]
        L.append("")
    L.append("Selection path: the best set of each size by cross-validated loss (noise-variance units); a "
             "larger set is named only if it beats the smaller one by "
             f"{100 * doc['config']['selection']['min_gain']:.0f} % in most folds, or by "
             f"{100 * doc['config']['selection']['strong_gain']:.0f} % where it acts (paired per-block t >= "
             f"{doc['config']['selection']['t_gain']:g}). The closest margin is the decision's statistic against "
             "its nearest threshold (relative); within 1e-9 it is numerical noise, decided against the larger "
             "set on every machine (\"on the edge\"):\n")
    L.append("| effects | best set | CV loss | gain | folds improved | paired t | runner-up (loss) | named | "
             "closest margin |")
    L.append("|---:|---|---:|---:|---:|---:|---|---|---:|")
    for s in doc["selection"]["path"]:
        best = ", ".join(f"`{e}`" for e in s["effects"]) or "(nominal)"
        runner = (", ".join(s["runner_up"]) + f" ({s['runner_up_loss']:.4g})") if s.get("runner_up") else "-"
        gain = f"{100 * s['gain']:.1f} %" if s["size"] else "-"
        share = f"{100 * s['fold_share']:.0f} %" if s["size"] else "-"
        med = f"{s['t']:.1f}" if s["size"] else "-"
        edge = "-" if "margin" not in s else (f"on the edge ({s['margin']:.1e}: {', '.join(s['on_edge'])})"
                                             if s["on_edge"] else f"{s['margin']:+.2g}")
        L.append(f"| {s['size']} | {best} | {s['loss']:.4g} | {gain} | {share} | {med} | {runner} | "
                 f"{'yes' if s['accepted'] else 'no'} | {edge} |")
    L.append("")
    if doc["selection"].get("equivalent"):
        L.append("Sets the data cannot tell from the named one (the simplest is named):\n")
        for e in doc["selection"]["equivalent"]:
            L.append(f"- {', '.join(f'`{x}`' for x in e['effects'])}: CV loss {e['loss']:.4g} "
                     f"(paired t {e['t']:.2f})")
        L.append("")
    L += _anatomy_table(res.get("anatomy") or {})
    for name, d in doc["selection"].get("torque_arbitration", {}).items():
        given = ", ".join(f"`{e}`" for e in d.get("given", [])) or "no other effect"
        L.append(f"Roll/pitch torque cannot arbitrate `{name}`: given {given}, the torque rows would need "
                 f"{d['torque_rows'][0]:.3g} (the force rows alone {d['force_rows'][0]:.3g}), beyond any plausible "
                 "C_T error: the measured roll/pitch torque is not the rotor map's (inertia, latency or smoothing "
                 f"of the attitude channel).  `{name}` is fitted on the force rows, where it is the same term as "
                 "`mass_error` (reported as confounded).\n")
    L += _slow_torque_lines(doc["selection"].get("slow_torque"))
    if doc["selection"].get("rejected"):
        L.append("Candidates not named on this data (unphysical, self-contradicting, or collinear with a "
                 "named effect):\n")
        for name, why in doc["selection"]["rejected"].items():
            L.append(f"- `{name}`: {why}.")
        L.append("")
    rem = doc.get("remainder") or {}
    if rem:
        L.append("## Beyond the catalog\n")
        L.append(rem.get("statement", ""))
        L.append("")
    r = doc["replay"]
    L.append(f"## Open-loop replay (restarted every {r['horizon_s']:g} s, driven by the measured rotor speeds)\n")
    L.append("| model | position RMSE at horizon (m) | x | y | z | attitude (deg) |")
    L.append("|---|---:|---:|---:|---:|---:|")
    for k in ("nominal", "extended"):
        ax = r[f"{k}_position_rmse_axes"] or [float("nan")] * 3
        L.append(f"| {k} | {r[f'{k}_position_rmse']:.4g} | {ax[0]:.3g} | {ax[1]:.3g} | {ax[2]:.3g} | "
                 f"{r[f'{k}_attitude_rmse_deg']:.3g} |")
    L.append("")
    ro = doc.get("rollout") or {}
    if ro.get("models"):
        from ..rollout import table

        L.append(f"## Multi-step rollout (held-out part, every start, H = {ro['horizon']} steps; `qr evaluate`)\n")
        L.append("Mean absolute error at step h: p (m), v (m/s), R (rad), w (rad/s); `hold` holds the state, "
                 "`rate_frozen` is the benchmark's physics baseline (nominal thrust, no drag, body rate held).\n")
        L += table(ro["models"], ro["horizon"])
        L.append("")
        ex = ro.get("explained")
        if ex:
            fmt = lambda x: "–" if x is None or x != x else f"{100 * x:.0f} %"  # noqa: E731
            L.append(f"Share of the held-out residual the named effects explain, sample by sample and summed "
                     f"over {ex['horizon']} samples (the slow error a rollout integrates):\n")
            L.append("| | " + " | ".join(AXES) + " |")
            L.append("|---|" + "---:|" * len(AXES))
            L.append("| one step | " + " | ".join(fmt(x) for x in ex["one_step"]) + " |")
            L.append(f"| summed over {ex['horizon']} | " + " | ".join(fmt(x) for x in ex["summed"]) + " |")
            L.append("")
    rem = doc.get("torque_remainder")
    if rem:
        L.append("## Learned torque remainder (a hybrid, not a cause)\n")
        L.append(f"A linear map of {rem['features']} (ridge {rem['ridge']:g}), fitted on the training part to the "
                 "torque the named effects leave, is written into `extended_vehicle.yaml` (`torque_remainder`) and "
                 "rolled out as `hybrid` above. Held-out torque RMSE x / y / z (N m): extended "
                 + " / ".join(f"{x:.2e}" for x in rem["extended_torque_rmse"]) + ", hybrid "
                 + " / ".join(f"{x:.2e}" for x in rem["hybrid_torque_rmse"]) + ".\n")
    if doc.get("refine"):  # qr.diagnose.refine (diagnose.refine=rollout)
        from .refine import report_lines

        L += report_lines(doc["refine"])
    acc = doc.get("accelerometer_check")
    if acc:
        from .accelerometer import statement

        L.append("## The force label against the accelerometer\n")
        L.append(statement(acc) + "\n")
    L.append("## Figures\n")
    for title, name in figs.items():
        L.append(f"### {title}\n\n![{title}](figures/{name})\n")
    L.append("## Extended model\n")
    L.append("`extended_vehicle.yaml`: the nominal vehicle plus the named effects; `qr synth`, the replay and the "
             "simulation study accept it.\n")
    from ..atomic import write_text

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


def make_figures(outdir: Path, res: dict, vehicle, anatomy=None) -> dict:
    """The report's figures into ``outdir/figures``; ``anatomy``: a :class:`BackgroundFigure` already
    drawing the residual anatomy."""
    figdir = outdir / "figures"
    figdir.mkdir(exist_ok=True)
    prep = res["prep"]
    test = prep.test
    step = max(1, int(test.sum()) // 20000)
    t = prep.t[test][::step]
    y = prep.y[test][::step]
    pred = res["pred_test"][::step]
    out = {}

    # flights (segments) one after another on the axis, never joined across flights or time gaps
    x, (y, pred), spans = figures.end_to_end(t, prep.flight[test][::step], y, pred)
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
    figures.save(fig, figdir / "residual_vs_effects.png")
    out["Held-out residual force and torque of the nominal model (grey; flights one after another, shaded "
        "alternately) and what the named effects explain (red): where red follows grey, a named effect "
        "accounts for it"] = "residual_vs_effects.png"

    fig, axs = figures.subplots(1, 2, figsize=(9, 3.2))
    for key, c in (("nominal", "grey"), ("extended", "C3")):
        g = res["replay"][key]["growth"]
        for j, a in enumerate("xyz"):
            axs[0].plot(g["elapsed"], g[f"e{a}"], color=c, ls=["-", "--", ":"][j], label=f"{key} {a}")
    axs[0].set_xlabel("time since restart (s)")
    axs[0].set_ylabel("RMS position error (m)")
    axs[0].legend(fontsize=6, ncol=2)
    err = res["replay"]["nominal"]["errors"]
    err = err[np.isfinite(err["ex"])]
    last = err.groupby("window").tail(1)
    worst = last.assign(e=np.sqrt(last.ex**2 + last.ey**2 + last.ez**2)).nlargest(3, "e")["window"]
    for k, wdw in enumerate(worst):
        for key, c in (("nominal", "grey"), ("extended", "C3")):
            e = res["replay"][key]["errors"]
            e = e[e["window"] == wdw]
            axs[1].plot(e["elapsed"], np.sqrt(e.ex**2 + e.ey**2 + e.ez**2), color=c, lw=1,
                        label=key if k == 0 else None)
    axs[1].set_xlabel("time since restart (s)")
    axs[1].set_ylabel("position error (m)")
    axs[1].set_title("three worst windows", fontsize=8)
    axs[1].legend(fontsize=7)
    figures.save(fig, figdir / "replay_drift.png")
    out["Open-loop replay: drift of the nominal and extended models"] = "replay_drift.png"

    if anatomy is None:
        anatomy_figure(prep, vehicle, figdir / "residual_anatomy.png")
    else:
        anatomy.collect(figdir / "residual_anatomy.png")
    out["Residual anatomy: nominal residual against body velocity, height, thrust and the rotor speeds "
        "(binned means, one colour per rotor)"] = \
        "residual_anatomy.png"
    return out


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
            "rotor speed u1..u4": s.u}  # the rotors share a panel: a weak one stands out by its colour
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
                ax.set_ylabel(AXES[i], fontsize=7)
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
