"""The filters run on one flight: :func:`estimate` (the three filters, the smoother, the likelihood tuning
and NIS consistency; the package docstring, :mod:`qr.estimation`, says what each one is) and
:func:`tuned_noise`."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..errors import QrInputError
from ..flight import check_not_frozen
from ..parallel import thread_map
from ..states import COLUMNS
from . import attitude_eskf, gyro, motor_kf, nis, position_kf
from .settings import DEFAULTS, FILTERS, resolve
from .tuning import ORDER, corner_hz, tune

MIN_SAMPLES = 10
P_COLS, Q_COLS, U_COLS = ["px", "py", "pz"], ["qw", "qx", "qy", "qz"], ["u1", "u2", "u3", "u4"]


def _inputs(flight: pd.DataFrame, source):
    missing = [c for c in ["t", *P_COLS, *Q_COLS, *U_COLS] if c not in flight.columns]
    if missing:
        raise QrInputError(source, f"flight lacks column(s) {', '.join(missing)}",
                           "pass a canonical flight (qr.flight.read_flight; docs/spec/flight-log.md)")
    t = flight["t"].to_numpy(dtype=float)
    if len(t) < MIN_SAMPLES or not np.all(np.diff(t) > 0):
        raise QrInputError(source, f"t must be strictly increasing with at least {MIN_SAMPLES} samples",
                           "read the flight with qr.flight.read_flight, which checks and sorts it")
    arrays = [flight[c].to_numpy(dtype=float) for c in (P_COLS, Q_COLS, U_COLS)]
    for name, a in zip(("position", "attitude"), arrays[:2]):
        if np.all(np.isfinite(a), axis=1).sum() < MIN_SAMPLES:
            raise QrInputError(source, f"fewer than {MIN_SAMPLES} samples with a complete {name}",
                               "the mocap lost the vehicle: check the log")
    dead = [c for c, col in zip(U_COLS, arrays[2].T) if np.isfinite(col).sum() < MIN_SAMPLES]
    if dead:
        raise QrInputError(source, f"rotor speed column(s) {', '.join(dead)} are (almost) empty",
                           "log all four rotor speeds")
    check_not_frozen(flight, source, rotors=True)  # filter=auto cannot tune on a signal without noise
    return (t, *arrays)


def _keep(t: np.ndarray, burn_in_s: float) -> np.ndarray:
    """Samples that count for NIS and likelihood: after the initial transient (at most half the flight)."""
    return t >= t[0] + min(float(burn_in_s), 0.5 * (t[-1] - t[0]))


TUNED_NIS_NOTE = ("tuned: q and r are scaled so each filter's mean NIS equals its dimension; judge "
                  "consistency by outside_sample_band (expected 1 - confidence)")


def _tune(s: dict, t, meas: dict, keep, speed_scale: float, progress: bool) -> dict:
    """Each filter's likelihood-tuned ``q``, ``r`` (:mod:`.tuning`); empty unless ``tune.enabled``."""
    if not s["tune"]["enabled"]:
        return {}
    from tqdm import tqdm

    # the noise is stationary: a long flight is tuned on its middle window (each search runs the
    # filter ~40 times)
    n, M = len(t), int(s["tune"]["max_samples"])
    w = slice((n - M) // 2, (n - M) // 2 + M) if n > M else slice(None)

    def one(f):
        return tune(f, t[w], meas[f][w], keep[w], s["tune"]["min_corner_hz"], int(s["tune"]["grid"]),
                    int(s["tune"]["rounds"]), speed_scale, s["attitude"]["reset_deg"])

    with tqdm(total=len(FILTERS), desc="filter=auto: likelihood search", disable=not progress) as bar:
        return dict(zip(FILTERS, thread_map(lambda f: (one(f), bar.update())[0], FILTERS)))


def tuned_noise(flight: pd.DataFrame, vehicle=None, cfg: dict | None = None, progress: bool = False,
                source: str | None = None) -> dict | None:
    """The ``tuning`` of :func:`estimate`'s report (None unless ``tune.enabled``), without
    filtering the flight afterwards: the callers that freeze the tuned values filter other rows."""
    s = resolve(cfg)
    if not s["tune"]["enabled"]:
        return None
    t, P, Qm, U = _inputs(flight, source or flight.attrs.get("source"))
    speed_scale = float(vehicle.hover_speed) if vehicle is not None else float(np.nanmedian(np.abs(U)))
    return _tune(s, t, {"position": P, "attitude": Qm, "motor": U}, _keep(t, s["nis"]["burn_in_s"]),
                 speed_scale, progress)


def estimate(flight: pd.DataFrame, vehicle=None, cfg: dict | None = None, progress: bool = False,
             source: str | None = None) -> tuple[pd.DataFrame, nis.NisReport]:
    """Filter (or smooth) a canonical flight into the state table.

    ``cfg`` is the ``filter`` config group as a dict (defaults: the thesis
    filters, :data:`DEFAULTS`); ``vehicle`` (optional) sets the rotor-speed
    scale of the rotor filters' initial covariance.  Returns the state table
    (``qr.states.COLUMNS`` plus ``sd_*`` posterior standard deviations and
    ``sd_thx..sd_thz``, the body-frame attitude error; ``nis_p``, ``nis_q``,
    ``nis_u1..4``, the per-sample NIS, NaN without an update) and its report (:class:`.nis.NisReport`:
    the noise values used, tuned ones for ``filter=auto``, and NIS statistics).
    """
    s = resolve(cfg)
    t, P, Qm, U = _inputs(flight, source or flight.attrs.get("source"))
    keep = _keep(t, s["nis"]["burn_in_s"])
    speed_scale = float(vehicle.hover_speed) if vehicle is not None else float(np.nanmedian(np.abs(U)))
    tuned = _tune(s, t, {"position": P, "attitude": Qm, "motor": U}, keep, speed_scale, progress)
    for f, v in tuned.items():
        s[f]["q"], s[f]["r"] = v["q"], v["r"]
    ((quat, psi, Va, blocks, inn_a, resets), gyro_report), (Xp, Vp, inn_p), (Xm, Vm, inn_m) = \
        _run_filters(flight, s, t, P, Qm, U, speed_scale, progress)
    w, al, sd_w, sd_al = attitude_eskf.body_rates(quat, psi, blocks)
    table = _state_table(t, Xp, quat, w, al, Xm)
    Vp, Va, Vm = (np.maximum(V, 0.0) for V in (Vp, Va, Vm))  # rounding can leave -0-ish variances
    table = pd.concat([table, _uncertainty_table(Vp, Va, sd_w, sd_al, Vm, inn_p, inn_a, inn_m)], axis=1)
    conf = float(s["nis"]["confidence"])
    nis_report = nis.FilterNis.of(inn_p, inn_a, inn_m, U_COLS, keep, conf)
    report = nis.NisReport(
        filter=s["name"], implementation=s["implementation"], smoother=bool(s["smoother"]),
        discretisation=s["discretisation"], samples=int(len(t)), duration_s=float(t[-1] - t[0]),
        dropouts={"position": int((~np.all(np.isfinite(P), axis=1)).sum()),
                  "attitude": int((~np.all(np.isfinite(Qm), axis=1)).sum()),
                  "motor": int((~np.isfinite(U)).sum())},
        noise=_noise(s), tuning=tuned or None, gyro=gyro_report or {"fused": False},
        attitude_restarts={"count": int(resets.sum()), "t": [float(x) for x in t[resets][:20]]},
        nis=nis_report, nis_burn_in_s=float(t[keep][0] - t[0]), inconsistent=nis_report.inconsistent(),
        nis_note=TUNED_NIS_NOTE if tuned else None)
    return table, report


def _run_filters(flight: pd.DataFrame, s: dict, t, P, Qm, U, speed_scale: float, progress: bool):
    """The three filters' outputs: ((attitude, the gyro's report), position, motor)."""
    disc, smooth, ref = s["discretisation"], bool(s["smoother"]), s["implementation"] == "reference"
    kw = dict(progress=progress) if ref else {}

    pf = position_kf.filter_reference if ref else position_kf.filter_fast
    mf = motor_kf.filter_reference if ref else motor_kf.filter_fast
    att = (t, Qm, s["attitude"]["q"], s["attitude"]["r"], disc, smooth)

    def attitude(**g):
        if ref:
            quat, psi, Ps, inn, resets = attitude_eskf.filter_reference(*att, reset_deg=s["attitude"]["reset_deg"],
                                                                         **kw, **g)
            return (quat, psi, *attitude_eskf.covariance_summary(Ps), inn, resets)
        return attitude_eskf.filter_fast(*att, reset_deg=s["attitude"]["reset_deg"], **g)

    def attitude_with_gyro():
        out = attitude()
        G = gyro.samples(flight) if s["attitude"]["gyro"] else None
        if G is None:
            return out, None
        quat, psi, _, blocks, _, _ = out  # a second pass with the gyro; the first gives its bias
        b = gyro.bias(G, attitude_eskf.body_rates(quat, psi, blocks)[0])
        rg = gyro.noise_variance(G)
        return attitude(gyro=G - b, r_gyro=rg), {"fused": True, "bias": [float(x) for x in b],
                                                "noise_sd": float(np.sqrt(rg)),
                                                "samples": int(np.all(np.isfinite(G), axis=1).sum())}

    tasks = [attitude_with_gyro,  # the longest first
             lambda: pf(t, P, s["position"]["q"], s["position"]["r"], disc, smooth, **kw),
             lambda: mf(t, U, s["motor"]["q"], s["motor"]["r"], disc, smooth, speed_scale=speed_scale, **kw)]
    # the three filters are independent: side by side on the compiled path (the reference path prints
    # progress bars, one at a time)
    return [f() for f in tasks] if ref else thread_map(lambda f: f(), tasks)


def _state_table(t, Xp, quat, w, al, Xm) -> pd.DataFrame:
    """The state estimate (``qr.states.COLUMNS``)."""
    cols = {"t": t}
    for i, name in enumerate(["p", "v", "a"]):
        for a, ax in enumerate("xyz"):
            cols[f"{name}{ax}"] = Xp[:, 3 * i + a]
    cols.update(dict(zip(Q_COLS, quat.T)))
    cols.update({f"w{ax}": w[:, a] for a, ax in enumerate("xyz")})
    cols.update({f"al{ax}": al[:, a] for a, ax in enumerate("xyz")})
    cols.update({f"u{i + 1}": Xm[:, i, 0] for i in range(4)})
    cols.update({f"ud{i + 1}": Xm[:, i, 1] for i in range(4)})
    return pd.DataFrame(cols)[COLUMNS]


def _uncertainty_table(Vp, Va, sd_w, sd_al, Vm, inn_p, inn_a, inn_m) -> pd.DataFrame:
    """The posterior standard deviations (``sd_*``) and the per-sample NIS (``nis_*``)."""
    sd = {}
    for i, name in enumerate(["p", "v", "a"]):
        for a, ax in enumerate("xyz"):
            sd[f"sd_{name}{ax}"] = np.sqrt(Vp[:, 3 * i + a])
    sd.update({f"sd_th{ax}": np.sqrt(Va[:, a]) for a, ax in enumerate("xyz")})
    sd.update({f"sd_w{ax}": sd_w[:, a] for a, ax in enumerate("xyz")})
    sd.update({f"sd_al{ax}": sd_al[:, a] for a, ax in enumerate("xyz")})
    sd.update({f"sd_u{i + 1}": np.sqrt(Vm[:, i, 0]) for i in range(4)})
    sd.update({f"sd_ud{i + 1}": np.sqrt(Vm[:, i, 1]) for i in range(4)})
    sd["nis_p"], sd["nis_q"] = inn_p.nis[:, 0], inn_a.nis[:, 0]
    sd.update({f"nis_{u}": inn_m.nis[:, i] for i, u in enumerate(U_COLS)})
    return pd.DataFrame(sd)


def _noise(s: dict) -> dict:
    """Each filter's noise as used (``q``, ``r``; with exact discretisation its corner frequency)."""
    noise = {}
    for f in FILTERS:
        noise[f] = {"q": s[f]["q"], "r": s[f]["r"]}
        if s["discretisation"] == "exact":
            noise[f]["corner_hz"] = corner_hz(float(np.mean(s[f]["q"])), s[f]["r"], ORDER[f])
    return noise
