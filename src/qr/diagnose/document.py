"""``diagnosis.json``, the machine contract of docs/spec/diagnosis.md, from a :class:`Diagnosis`.

:func:`document` is the one function that makes it; :func:`stated` is the same document with the
numbers that are not finite left as NaN (the report prints them as such: the report and the file state
the same digits).
"""

from __future__ import annotations

from ..atomic import finite_or_null
from ..torque_remainder import FEATURES
from .diagnosis import Diagnosis
from .slow_torque import SlowBalance

SCHEMA = "qr.diagnosis/1"
# the noise floor: the filters' posterior covariance through the labels, calibrated per axis on the
# cross-fitting halves (qr.diagnose.noise)
NOISE_SOURCE = "filter covariance"


def _r(x, n=6):
    return [float(f"{v:.{n}g}") for v in x]


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


def _slow_json(slow: SlowBalance | None) -> dict | None:
    if slow is None:
        return None
    axes = [{k: (float(f"{v:.4g}") if isinstance(v, float) else v) for k, v in a.record().items()} for a in slow.axes]
    return {**slow.record(), "axes": axes}


def _split(windows: list[dict]) -> dict:
    ms = lambda w: [round(float(x), 3) for x in w]  # noqa: E731  (on the file's t axis, which may be a clock)
    return {"train": ms(windows[0]["train"]), "test": ms(windows[0]["test"]),
            "per_flight": [{"train": ms(w["train"]), "test": ms(w["test"])} for w in windows]}


def _replay(d: Diagnosis) -> dict:
    rep_n, rep_e = d.replay.nominal.summary, d.replay.extended.summary
    return {
        "horizon_s": float(d.settings.given["horizon_s"]),
        "nominal_position_rmse": float(f"{rep_n.position_rmse:.6g}"),
        "extended_position_rmse": float(f"{rep_e.position_rmse:.6g}"),
        "nominal_position_rmse_axes": _r(rep_n.position_rmse_axes),
        "extended_position_rmse_axes": _r(rep_e.position_rmse_axes),
        "nominal_attitude_rmse_deg": float(f"{rep_n.attitude_rmse_deg:.4g}"),
        "extended_attitude_rmse_deg": float(f"{rep_e.attitude_rmse_deg:.4g}"),
        "windows": rep_n.windows,
    }


def _selection(d: Diagnosis) -> dict:
    sel = d.fit.selection
    return {"cv_loss_nominal": float(f"{sel.loss_nominal:.6g}"), "cv_loss_final": float(f"{sel.loss_final:.6g}"),
            "path": [_clean(s) for s in sel.path], "equivalent": [_clean(s) for s in sel.equivalent],
            "rejected": sel.rejected, "not_named": d.not_named,
            "torque_arbitration": {k: {"force_rows": _r(a.force_rows, 4), "torque_rows": _r(a.torque_rows, 4),
                                       "given": a.given} for k, a in d.fit.arbitration.items()},
            "slow_torque": _slow_json(d.fit.slow)}


def _axes(x: list[float]) -> dict:
    return {"force_rmse": _r(x[:3]), "torque_rmse": _r(x[3:])}


def segments_json(names: list[str], split) -> dict:
    """The account of the data used: airborne windows, time gaps, segments (flight time, s)."""
    r = lambda x: round(float(x), 4)  # noqa: E731
    airborne, gaps, segments = [], [], []
    for name, fs in zip(names, split):
        airborne.append({"flight": name, "window": [r(fs.airborne[0][0]), r(fs.airborne[-1][1])],
                         "dropped_s": r(fs.ground_s)})
        if len(fs.airborne) > 1:
            airborne[-1]["windows"] = [[r(a), r(b)] for a, b in fs.airborne]
        gaps += [{"flight": name, "from": r(a), "to": r(b)} for a, b in fs.gaps]
        for seg in fs.segments:
            segments.append({"flight": name, "window": [r(x) for x in seg.window], "samples": len(seg.rows),
                             "used": seg.used, **({"note": seg.note} if seg.note else {})})
    return {"airborne": airborne, "time_gaps": gaps, "segments": segments}


def stated(d: Diagnosis) -> dict:
    """``diagnosis.json``'s content, a number that is not finite left as NaN."""
    h, tr = d.held_out, d.torque_remainder
    return {
        "schema": SCHEMA,
        "flights": d.flights.names,
        "samples": int(len(d.labels.full.t)),
        "split": _split(d.labels.full.windows),
        "nominal": _axes(h.nominal_rmse),
        "effects": [e.stated() for e in d.effects],
        # a named constant moment the wind the named force implies would make (qr.diagnose.wind)
        **({"wind_moment": [m.record() for m in d.fit.wind]} if d.fit.wind else {}),
        "extended": _axes(h.extended_rmse),
        "replay": _replay(d),
        "rollout": d.rollout.record(),
        "noise_floor": {**_axes(h.noise_floor_rmse), "source": NOISE_SOURCE},
        "remainder": d.remainder.record(),
        "anatomy": {k: _r(v, 4) for k, v in h.anatomy.items()},
        "selection": _selection(d),
        "verdict": d.verdict,
        # the held-out residual's weighted mean square (noise-variance units) the verdict states
        "losses": {"nominal": float(f"{h.nominal_loss:.6g}"), "extended": float(f"{h.extended_loss:.6g}")},
        "described": d.described,
        **({"misfit": {k: float(f"{v:.4g}") for k, v in h.misfit.record().items()}} if h.misfit else {}),
        "config": d.settings.given,
        "filter": d.settings.filter,
        "accelerometer_check": d.accelerometer.record() if d.accelerometer is not None else None,
        **({"torque_remainder": {"ridge": tr.ridge, "features": FEATURES, "extended_torque_rmse":
                                 tr.extended_torque_rmse, "hybrid_torque_rmse": tr.hybrid_torque_rmse}}
           if tr is not None else {}),
        **segments_json(d.flights.names, d.flights.split),
        "conventions": [c.record() for c in d.flights.conventions],
        **({"refine": d.refinement.to_json()} if d.refinement is not None else {}),
        "vehicle_file": [c.record() for c in d.vehicle_file],
        "vehicle_file_unresolved": [c.record() for c in d.vehicle_file_unresolved],
    }


def document(d: Diagnosis) -> dict:
    """``diagnosis.json``: strict JSON, a number that is not finite null and ``notes`` saying why."""
    return note_nulls(stated(d))


def note_nulls(doc: dict) -> dict:
    """``doc`` as strict JSON: a number that is not finite becomes null, and ``notes`` says why."""
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
    return {**doc, "notes": notes} if notes else doc


def vehicle_header(d: Diagnosis) -> str:
    """``extended_vehicle.yaml``'s header: what the file holds, from the diagnosis."""
    said = ("the vehicle as given, nothing added: the model does not describe this flight (diagnosis.json: "
            "described, misfit; what it identifies is in its effects)" if not d.described else
            "the nominal parameters plus the named effects"
            + ("; their parameters and J, C_T, C_Q, the delay refined by the rollout's error where the refinement "
               "may write them (diagnosis.json: refine)" if d.refinement is not None else ""))
    return f"Extended vehicle from qr diagnose of {', '.join(d.flights.names)}: {said}"


def run_metrics(doc: dict) -> dict:
    """A diagnosis's MLflow metrics from its document: effects named, replay RMSEs, and the rollout block's
    ``rollout.<model>.<q>_at_<H>`` and ``..._ratio`` (to rate_frozen)."""
    from ..rollout import horizon_metrics

    ro = doc.get("rollout")
    return {"effects_named": len(doc["effects"]),
            "replay.nominal_position_rmse": doc["replay"]["nominal_position_rmse"],
            "replay.extended_position_rmse": doc["replay"]["extended_position_rmse"],
            **(horizon_metrics(ro["models"], ro["horizon"], prefix="rollout.", ratios=True)
               if ro and ro.get("models") else {})}
