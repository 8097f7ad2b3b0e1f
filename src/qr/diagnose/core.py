"""The diagnosis of one or more filtered flights: residuals, effects, extended model, gains.

``diagnose`` takes state tables (from the filters) and the raw flights (for the
replay against measurements) and returns everything ``diagnosis.json`` and the
report need.  It does no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import reduce

import numpy as np
import pandas as pd

from ..dynamics import residuals
from ..flight import on_stamps
from ..effects import CATALOG, Signals, plausible_bounds, total_term
from ..identification import delay as delay_mod
from ..identification.bootstrap import bootstrap
from ..identification.normal_equations import (BlockStats, Columns, accumulate, bounded_noise, design, fit, loss,
                                                regressor_noise, row_sums)
from ..identification.edge import EDGE, Margins
from ..identification.selection import ROWS, select, torque_arbitration
from ..parallel import thread_map, workers
from ..states import signals
from ..torque_remainder import torque as remainder_torque
from . import replay as replay_mod
from . import slow_torque as slow_mod
from .noise import calibrate, noise_sd
from .settings import DiagnoseConfig  # noqa: F401  (the settings and their allowed values live in .settings)

AXES = ["fx", "fy", "fz", "tx", "ty", "tz"]
CHUNK = 20000
# Errors in variables: regressors from the other cross-fitting half carry their own noise, which
# attenuates slopes and favours whichever explanation uses the least noisy signal; the halves'
# regressor differences at the same stamps measure that noise, and it is taken out of XᵀWX.
EIV = True


@dataclass
class Prepared:
    """All flights stacked: signals, residual labels, noise, and where each sample belongs."""

    s: Signals
    y: np.ndarray  # (N, 6)
    sd: np.ndarray  # (N, 6)
    t: np.ndarray
    flight: np.ndarray  # per sample: index of its state table (a flight, or a segment of one)
    train: np.ndarray  # bool
    test: np.ndarray  # bool
    block: np.ndarray  # block id per training sample (-1 elsewhere)
    windows: list[dict]  # per flight: train/test windows in the flight's own time
    # What effect designs read: ``s`` with the rotor signals delayed by the actuator-delay estimate
    # and the delay's design column (``at_delay``); None: ``s`` itself.  Labels never change.
    ds: Signals | None = None
    # cross-fitting data: row i + pair_offset is row i's stamp with the other half's label and regressors
    pair_offset: int = 0
    # the rotor signals the labels themselves were built from (cross-fitting: the label's own half); the
    # exact delay term is a transform of the label, not a regressor: W(u(t - d)) - W(u(t)) from the same
    # measurements leaves rotor noise of the same size whatever d, so the delay search is unbiased
    own_u2: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def design_s(self) -> Signals:
        return self.s if self.ds is None else self.ds


def flight_of(states_list: list[pd.DataFrame]) -> list[int]:
    """The flight each state table belongs to: ``attrs["flight"]`` for a segment of one, else its position."""
    return [int(st.attrs.get("flight", i)) for i, st in enumerate(states_list)]


def _cut(spans: list[tuple[float, float]], fraction: float) -> float:
    """The time at which ``fraction`` of the segments' summed duration lies before it (inside a segment)."""
    target, acc = fraction * sum(b - a for a, b in spans), 0.0
    for a, b in spans:
        if acc + (b - a) >= target:
            return a + (target - acc)
        acc += b - a
    return spans[-1][1]


def prepare(states_list: list[pd.DataFrame], vehicle, cfg: DiagnoseConfig) -> Prepared:
    """Stack state tables: each is trimmed by ``trim_s`` at both ends (filter transients), cut in blocks.

    A table with ``attrs["flight"]`` is one gap-free segment of that flight (``qr.segments``):
    each flight is split once, at ``train_fraction`` of its segments' summed (trimmed) time,
    with ``gap_s`` between its training and test samples; a block never spans two segments.
    """
    owner = flight_of(states_list)
    keeps = []
    for st in states_list:
        t = st["t"].to_numpy()
        keeps.append((t >= t[0] + cfg.trim_s) & (t <= t[-1] - cfg.trim_s))
    cuts, windows = {}, []
    for f in sorted(set(owner)):
        spans = [(st["t"].to_numpy()[k][0], st["t"].to_numpy()[k][-1])
                 for st, k, o in zip(states_list, keeps, owner) if o == f and k.any()]
        if not spans:
            raise ValueError(f"flight {f}: no sample left after trimming trim_s={cfg.trim_s} s at each end")
        cut = cuts[f] = _cut(spans, cfg.train_fraction)
        windows.append({"train": [float(spans[0][0]), float(cut - cfg.gap_s / 2)],
                        "test": [float(cut + cfg.gap_s / 2), float(spans[-1][1])]})
    parts, blocks_next = [], 0
    for i, (st, keep) in enumerate(zip(states_list, keeps)):
        if not keep.any():
            continue
        st = st[keep].reset_index(drop=True)
        t = st["t"].to_numpy()
        s = signals(st)
        y = residuals(s, vehicle)
        if vehicle.effects:  # an extended vehicle: diagnose what its effects leave
            y = y - total_term(vehicle.effects, s, vehicle)
        y[:, 3:6] -= remainder_torque(vehicle, s.v_b, s.omega, s.u)  # and its learned remainder
        sd = noise_sd(st, s.R, vehicle, y)
        cut = cuts[owner[i]]
        train = t < cut - cfg.gap_s / 2
        test = t >= cut + cfg.gap_s / 2
        block = np.full(len(t), -1)
        rel = t[train] - t[0]
        block[train] = blocks_next + (rel // cfg.block_s).astype(int)
        if train.any():
            used = np.unique(block[train])
            remap = {b: blocks_next + j for j, b in enumerate(used)}
            block[train] = [remap[b] for b in block[train]]
            blocks_next += len(used)
        parts.append((s, y, sd, t, np.full(len(t), i), train, test, block))
    cat = lambda k: np.concatenate([p[k] for p in parts])  # noqa: E731
    s_all = Signals.concat([p[0] for p in parts])
    return Prepared(s_all, cat(1), cat(2), cat(3), cat(4), cat(5), cat(6), cat(7), windows)


def prepare_cross(pairs: list[tuple[pd.DataFrame, pd.DataFrame]], vehicle, cfg: DiagnoseConfig) -> Prepared:
    """Fitting data from disjoint-measurement filters: labels of one half, regressors of the other."""
    a = prepare([p[0] for p in pairs], vehicle, cfg)
    b = prepare([p[1] for p in pairs], vehicle, cfg)
    s = Signals.concat([b.s, a.s])
    cat = lambda k: np.concatenate([getattr(a, k), getattr(b, k)])  # noqa: E731
    return Prepared(s, cat("y"), cat("sd"), cat("t"), cat("flight"), cat("train"), cat("test"), cat("block"),
                    a.windows, pair_offset=len(a.t),
                    own_u2=(np.concatenate([a.s.u2_force, b.s.u2_force]), np.concatenate([a.s.u2_torque, b.s.u2_torque])))


def weights(sd: np.ndarray) -> np.ndarray:
    floor = 1e-3 * np.nanmedian(sd, axis=0)
    return 1.0 / np.maximum(sd, floor) ** 2


def block_stats(prep: Prepared, vehicle, cols: Columns, y: np.ndarray | None = None, rows=None,
                s: Signals | None = None):
    """Per-block normal equations; designs read ``s`` (default: ``prep.design_s``).

    ``rows`` restricts the loss to some of the six axes; a list of such restrictions (``None`` for all
    rows) gives one ``BlockStats`` each, from one pass over the designs.
    """
    many = isinstance(rows, list) and (not rows or not np.isscalar(rows[0]))
    row_sets = rows if many else [rows]
    y = prep.y if y is None else y
    s_design = prep.design_s if s is None else s
    idx = np.flatnonzero(prep.train)
    n_blocks = int(prep.block[idx].max()) + 1 if idx.size else 0
    p = cols.size
    w0 = weights(prep.sd)
    lb = np.concatenate([plausible_bounds(e, vehicle)[0] - CATALOG[e].neutral for e in cols.effects] + [[]])
    ub = np.concatenate([plausible_bounds(e, vehicle)[1] - CATALOG[e].neutral for e in cols.effects] + [[]])
    n = prep.pair_offset
    if n and EIV:  # cross-fitting halves: rows i and i + n, labels and regressors swapped
        idx = idx[idx < n]

    def chunks(starts):
        """The statistics of a run of chunks, summed in order (from zeros)."""
        acc = (np.zeros((6, n_blocks, p, p)), np.zeros((6, n_blocks, p)), np.zeros((6, n_blocks)), np.zeros(n_blocks))
        noise = np.zeros((6, n_blocks, p, p))
        for start in starts:
            sl = idx[start:start + CHUNK]
            parts = [sl, sl + n] if n and EIV else [sl]
            Xs = [design(s_design.take(r), vehicle, cols) for r in parts]
            for r, X in zip(parts, Xs):
                accumulate(X, y[r], w0[r], prep.block[r], n_blocks, out=acc)
            if len(Xs) == 2:  # the regressors' own noise, which the fit would otherwise count as signal
                regressor_noise(Xs[1] - Xs[0], 0.5 * (w0[parts[0]] + w0[parts[1]]), prep.block[sl], n_blocks,
                                out=noise)
        return (*acc, noise)

    # contiguous runs of chunks side by side (numpy releases the GIL); a block lies in one run, or at a
    # run's edge, so its sums are the same as from one pass
    starts = np.arange(0, idx.size, CHUNK)
    runs = [r for r in np.array_split(starts, min(workers(), max(len(starts), 1))) if len(r)]
    done = thread_map(chunks, runs) or [chunks([])]
    total = [reduce(np.add, [x[k] for x in done]) for k in range(5)]
    acc, noise = tuple(total[:4]), total[4]
    out = []
    for rows in row_sets:
        G, N = row_sums(acc[0], rows), row_sums(noise, rows)
        out.append(BlockStats(G - bounded_noise(G, N), row_sums(acc[1], rows), row_sums(acc[2], rows), acc[3].copy(),
                              cols, lb, ub))
    return out if many else out[0]


def predict(s: Signals, vehicle, effects: list[str], theta: np.ndarray, force_only=()) -> np.ndarray:
    if not effects:
        return np.zeros((len(s), 6))
    cols = Columns.of(effects, force_only)
    out = np.zeros((len(s), 6))
    for start in range(0, len(s), CHUNK):
        sl = slice(start, start + CHUNK)
        out[sl] = design(s.take(sl), vehicle, cols) @ theta
    return out


def extended_prediction(prep: Prepared, vehicle, named: list[str], theta: np.ndarray, idx=None,
                        force_only=()) -> np.ndarray:
    """Terms of the named effects on samples ``idx`` of ``prep``; the delay by its exact map."""
    idx = np.arange(len(prep.t)) if idx is None else idx
    s = prep.design_s.take(idx)
    if "actuator_delay" not in named:
        return predict(s, vehicle, named, theta, force_only)
    others = [e for e in named if e != "actuator_delay"]
    cols = Columns.of(named)
    d = float(theta[cols.slices["actuator_delay"]][0])
    return predict(s, vehicle, others, theta[cols.index(others)], force_only) + exact_delay_term(prep, vehicle, d)[idx]


def to_parameters(effects: list[str], theta: np.ndarray, se: np.ndarray | None = None):
    out, cols = [], Columns.of(effects)
    for e in effects:
        sl = cols.slices[e]
        eff = CATALOG[e]
        params = {p: float(v + n) for p, v, n in zip(eff.params, theta[sl], eff.neutral)}
        errs = {p: float(x) for p, x in zip(eff.params, se[sl])} if se is not None else {}
        out.append({"name": e, "parameters": params, "stderr": errs})
    return out


def rms(x: np.ndarray, axis=0) -> np.ndarray:
    return np.sqrt(np.nanmean(x**2, axis=axis))


def refine_delay(prep: Prepared, vehicle, named: list[str], theta: np.ndarray, cfg: DiagnoseConfig,
                 force_only=()):
    """The delay by its exact delayed rotor map, jointly with the other named effects (1-D search).

    Returns the refined delay and the other effects' parameters.
    """
    others = [e for e in named if e != "actuator_delay"]
    cols = Columns.of(others, force_only)

    def train_loss(d):
        yd = prep.y - exact_delay_term(prep, vehicle, d)
        st = block_stats(prep, vehicle, cols, yd, s=at_delay(prep, vehicle, d))
        th = fit(st, others) if others else np.zeros(0)
        G, h, s, n = st.total
        return loss(G, h, s, n, th), th

    d1 = float(theta[Columns.of(named).slices["actuator_delay"]][0])
    hi = min(cfg.delay_max_s, max(2 * abs(d1), 0.01))
    d = delay_mod.estimate(lambda x: train_loss(x)[0], hi, 0.0, n_grid=11)
    return d, train_loss(d)[1]


def exact_delay_term(prep: Prepared, vehicle, d: float, rows: np.ndarray | None = None) -> np.ndarray:
    """Residual of a rotor map acting ``d`` late: ``W(u(t - d)) - W(u(t))`` on f_z and τ (N, 6; or
    ``rows``)."""
    u2f, u2t = prep.own_u2 or (prep.s.u2_force, prep.s.u2_torque)
    return delay_mod.exact_term(prep.t, prep.flight, u2f, u2t, vehicle.rotors.matrix, d, rows)


def at_delay(prep: Prepared, vehicle, d: float, column: str = "secant", shift: float | None = None) -> Signals:
    """``prep.s`` as effect designs read it when the rotor map acts ``d`` late: rotor signals ``shift``
    (default ``d``) late, and actuator_delay's column (the secant through 0 and ``d``, at least one
    sample; or the tangent at ``d``)."""
    from dataclasses import replace

    shift = d if shift is None else shift
    args = (prep.t, prep.flight, prep.s.u2_force, prep.s.u2_torque, vehicle.rotors.matrix)
    dt = float(np.median(np.diff(prep.t[:1000]))) if len(prep.t) > 1 else 0.01
    if column == "secant":
        col = delay_mod.secant_column(*args, max(d, dt))
    else:
        col = delay_mod.tangent_column(*args, d, step=0.5 * dt)
    shifted = lambda x: delay_mod.shift(prep.t, prep.flight, x, shift)  # noqa: E731
    return replace(prep.s, u2f=shifted(prep.s.u2_force), u2t=shifted(prep.s.u2_torque), u2f_dot=None, u2t_dot=None,
                   delay_column=col)


def first_delay(prep: Prepared, vehicle, cfg: DiagnoseConfig) -> float:
    """A first estimate of an actuator delay, by the exact map alone on the training part.

    Other effects are slow next to the delay's signature (the rotor map's rate), so they barely move it.
    """
    w = weights(prep.sd)
    tr = np.flatnonzero(prep.train & np.isfinite(prep.y).all(axis=1))
    y, w = prep.y[tr], w[tr]
    return delay_mod.estimate(lambda d: float(np.sum(w * (y - exact_delay_term(prep, vehicle, d, tr)) ** 2)),
                              cfg.delay_max_s, 0.0)


def diagnose(states_list: list[pd.DataFrame], measured_list: list[pd.DataFrame], vehicle,
             cfg: DiagnoseConfig, seed: int = 0, progress=None, pairs=None, prepared=None) -> dict:
    """``pairs``: per flight the (even, odd) half-sample state tables for cross-fitting (recommended);
    ``prepared(prep)``: called with the nominal residuals as soon as they exist."""
    step = progress or (lambda msg: None)
    if pairs:  # the labels of the full flight and of the cross-fitting halves, side by side
        prep, fitprep = thread_map(lambda f: f(), (lambda: prepare(states_list, vehicle, cfg),
                                                   lambda: prepare_cross(pairs, vehicle, cfg)))
    else:
        prep = fitprep = prepare(states_list, vehicle, cfg)
    if prepared is not None:  # after the threads: a fork beside a running thread could inherit its locks
        prepared(prep)
    noise_scale = calibrate(fitprep, prep) if pairs else None
    candidates = [e for e in (cfg.candidates or list(CATALOG)) if e not in cfg.exclude]
    d0 = None
    if "actuator_delay" in candidates:
        step("actuator delay: first estimate")
        d0 = first_delay(fitprep, vehicle, cfg)
        for p in {id(x): x for x in (prep, fitprep)}.values():
            p.ds = at_delay(p, vehicle, d0, shift=0.0)
    step("normal equations")

    def statistics(cols):
        """All rows, and the rows of each ``ROWS`` group alone."""
        all_rows, *groups = block_stats(fitprep, vehicle, cols, rows=[None, *ROWS.values()])
        return all_rows, dict(zip(ROWS, groups))

    def selection(force_only=frozenset()):
        stats, rows = statistics(Columns.of(candidates, force_only))
        sel = select(stats, cfg.selection, rows)
        # May the roll/pitch torque arbitrate C_T?  Judged given what the data do contain (this
        # selection's effects): if the torque rows still put thrust_gain on its bound, select again
        # with thrust_gain fitted on the force rows alone.
        arb = torque_arbitration((rows["force"], rows["torque"]),
                                 base=[e for e in sel.named if e != "thrust_gain"]) \
            if "thrust_gain" in candidates and "thrust_gain" not in sel.named and not force_only else {}
        if arb:
            stats, rows, sel, _ = selection(frozenset(arb))
        return stats, rows, sel, arb

    step("selection")
    stats, rows, sel, arb = selection()
    force_only = frozenset(arb) or stats.cols.force_only
    d = None
    if "actuator_delay" in sel.named:
        # a delayed rotor map delays every rotor-map effect (a C_Q error acts on the late yaw torque):
        # with the delay named, the others are judged again through the late rotor map
        step("exact delay")
        d, _ = refine_delay(fitprep, vehicle, sel.named, fit(stats, sel.named), cfg, force_only)
        for p in {id(x): x for x in (prep, fitprep)}.values():
            p.ds = at_delay(p, vehicle, d)
        stats, rows, sel, arb_again = selection(force_only)
        arb = arb_again or arb
        force_only = stats.cols.force_only
    named = sel.named
    theta = fit(stats, named) if named else np.zeros(0)
    boot_stats = stats
    if "actuator_delay" in named:
        d, th_other = refine_delay(fitprep, vehicle, named, theta, cfg, force_only)
        others = [e for e in named if e != "actuator_delay"]
        theta = theta.copy()
        theta[Columns.of(named).index(others)] = th_other
        theta[Columns.of(named).slices["actuator_delay"]] = d
        # the bootstrap repeats the whole estimator, delay search included, to first order: the model
        # linearised at d (a Gauss-Newton step from d, whose fixed point is the estimate)
        s_lin = at_delay(fitprep, vehicle, d, "tangent")
        y_lin = fitprep.y - exact_delay_term(fitprep, vehicle, d) + d * s_lin.delay_column
        boot_stats = block_stats(fitprep, vehicle, Columns.of(named, force_only), y_lin, s=s_lin)
        prep.ds = at_delay(prep, vehicle, d)  # the extended model's other rotor-map effects act d late
    elif d is not None:  # the delay did not survive the second pass: back to the rotor map on time
        prep.ds = at_delay(prep, vehicle, d0, shift=0.0)
    step("bootstrap")
    boot = bootstrap(boot_stats, named, cfg.selection.bootstrap, seed) if named else np.zeros((0, 0))
    # resampling B blocks underestimates the variance of p fitted parameters by (B - p)/B (as a
    # sample variance without its degrees-of-freedom correction): the s.e. carry that factor back
    used = int(np.count_nonzero(boot_stats.n)) if named else 0
    dof = np.sqrt(used / (used - boot.shape[1])) if named and used > boot.shape[1] + 1 else 1.0
    se = boot.std(axis=0, ddof=1) * dof if named else np.zeros(0)

    slow = None
    if cfg.slow_torque_horizon and slow_mod.EFFECT in candidates and slow_mod.EFFECT not in named:
        step("slow torque balance")
        resid = fitprep.y - extended_prediction(fitprep, vehicle, named, theta, None, force_only)
        slow = slow_mod.slow_torque(fitprep, vehicle, resid, cfg.slow_torque_horizon, cfg.selection.folds,
                                    cfg.selection.t_name, cfg.slow_torque_min_gain, cfg.selection.bootstrap, seed)
    fixed = {}  # effects whose parameters come from outside the one-step fit
    if slow and slow["named"]:
        ax = slow["axes"]
        fixed[slow_mod.EFFECT] = (np.array([a["estimate"] if a["named"] else 0.0 for a in ax]),
                                  np.array([a["stderr"] if a["named"] else np.nan for a in ax]))
        old = Columns.of(named)
        named = sorted(named + [slow_mod.EFFECT], key=list(CATALOG).index)
        new = Columns.of(named)
        th, s2 = np.zeros(new.size), np.zeros(new.size)
        for e in named:
            th[new.slices[e]], s2[new.slices[e]] = fixed[e] if e in fixed else (theta[old.slices[e]], se[old.slices[e]])
        theta, se = th, s2

    def refit(effects):
        """One-step fit of ``effects`` on the training part, the slow-balance parameters kept."""
        own = [e for e in effects if e not in fixed]
        th_own, own_cols = (fit(stats, own) if own else np.zeros(0)), Columns.of(own)
        cols = Columns.of(effects)
        out = np.zeros(cols.size)
        for e in effects:
            out[cols.slices[e]] = fixed[e][0] if e in fixed else th_own[own_cols.slices[e]]
        return out

    # held-out support is judged on the cross-fitted data (labels from one half-sample filter, regressors
    # from the other), as the fit: with one filter's rotor speeds in both, an effect on the rotor map
    # (a C_Q gain above 1) scales the labels' own rotor noise and looks worse than it is
    judge = HeldOut(fitprep, vehicle, force_only, fixed, slow)
    dropped = {}
    while True:
        explained = judge.explained(named, theta, refit)
        why = unsupported(named, explained, judge.y, judge.residual(named, theta), judge.w, cfg.selection.min_gain,
                          lambda rest: judge.residual(rest, refit(rest)))
        if not why:
            break
        e, reason = why
        dropped[e] = reason
        step(f"not named: {e} ({reason})")
        old = Columns.of(named)
        named = [x for x in named if x != e]
        if e == "actuator_delay":  # the other effects act on the rotor map on time again
            for p in {id(x): x for x in (prep, fitprep)}.values():
                p.ds = at_delay(p, vehicle, d0, shift=0.0)
            stats = boot_stats = block_stats(fitprep, vehicle, Columns.of(candidates, force_only))
            judge = HeldOut(fitprep, vehicle, force_only, fixed, slow)
        keep = old.index(named)
        theta = refit(named)
        own = [x for x in named if x not in fixed]
        if own:  # standard errors of the smaller set's own fit, as for the named set above
            boot = bootstrap(boot_stats, own, cfg.selection.bootstrap, seed)
            used = int(np.count_nonzero(boot_stats.n))
            dof = np.sqrt(used / (used - boot.shape[1])) if used > boot.shape[1] + 1 else 1.0
            se_own, own_cols = boot.std(axis=0, ddof=1) * dof, Columns.of(own)
            se = se[keep].copy()
            new = Columns.of(named)
            for x in own:
                se[new.slices[x]] = se_own[own_cols.slices[x]]
        else:
            se = se[keep]
    effects = to_parameters(named, theta, se)
    from .coefficients import evidence

    identified = evidence(stats, named, fixed)
    for e in effects:
        e["explained_fraction"] = explained[e["name"]]
        e["confounded_with"] = sel.confounded.get(e["name"], [])

    test = prep.test
    s_test = prep.design_s.take(np.flatnonzero(test))
    y_test = prep.y[test]
    pred_test = extended_prediction(prep, vehicle, named, theta, np.flatnonzero(test), force_only)
    w_test = weights(prep.sd)[test]
    base_loss = float(np.nanmean(w_test * y_test**2))
    ext_resid = y_test - pred_test
    misfit = model_misfit(ext_resid, vehicle)
    if misfit:  # nothing the catalog explains is a finding on a flight the model does not describe
        for e in named:
            dropped[e] = "the model does not describe this flight, so no effect is a finding"
        named, theta, se, effects = [], np.zeros(0), np.zeros(0), []
        pred_test = np.zeros_like(y_test)
        ext_resid = y_test

    result = {
        "samples": int(len(prep.t)),
        "windows": prep.windows,
        "nominal_rmse": rms(y_test).tolist(),
        "extended_rmse": rms(ext_resid).tolist(),
        "noise_floor_rmse": rms(prep.sd[test]).tolist(),
        "nominal_loss": base_loss,
        "extended_loss": float(np.nanmean(w_test * ext_resid**2)),
        "effects": effects,
        "selection": {"path": sel.path, "equivalent": sel.equivalent, "cv_loss_nominal": sel.loss_nominal,
                      "cv_loss_final": sel.loss_final, "rejected": sel.rejected, "not_named": dropped},
        "noise_scale": noise_scale,
        "delay_first_estimate": d0,
        "bootstrap": boot,
        "prep": prep,
        "fitprep": fitprep,
        "theta": theta,
        "named": named,
        "pred_test": pred_test,
        "force_only": force_only,
        "torque_arbitration": arb,
        "slow_torque": slow,
        "evidence": identified,
        "misfit": misfit,
    }
    result["anatomy"] = anatomy(stats, s_test, y_test, prep.sd[test], vehicle, candidates, force_only)
    step("replay")
    result["replay"] = _replay_all(states_list, measured_list, vehicle, effects, cfg, prep)
    return result


AXES_SAID = ("f_x", "f_y", "f_z", "τ_x", "τ_y", "τ_z")
# A rigid-body model with the catalog's effects describes a flight whose held-out residual, after the best
# extension, stays below this share of the weight (force) and of the weight's torque at the arm (torque):
# drag, biases and rotor errors of any real quadrotor leave a few per cent (the measured Crazyflie flights:
# 1-7 %); a log in another frame or unit, a tether, a crash leave tens of per cent or more.
MISFIT = 0.1


def model_misfit(resid: np.ndarray, vehicle) -> dict | None:
    """Where the held-out residual (N, 6) is beyond ``MISFIT`` of the vehicle's scales: the shares; else None."""
    arm = float(np.max(np.hypot(*vehicle.rotors.positions.T)))
    weight = vehicle.mass * 9.81
    force = float(np.sqrt(np.nanmean(np.nansum(resid[:, :3] ** 2, axis=1)))) / weight
    torque = float(np.sqrt(np.nanmean(np.nansum(resid[:, 3:] ** 2, axis=1)))) / (weight * arm)
    if max(force, torque) <= MISFIT:
        return None
    return {"force_of_weight": force, "torque_of_weight_at_arm": torque, "limit": MISFIT}


class HeldOut:
    """The held-out rows of a prepared data set, and what a named set explains there."""

    def __init__(self, prep: Prepared, vehicle, force_only, fixed: dict, slow: dict | None):
        self.prep, self.vehicle, self.force_only, self.fixed, self.slow = prep, vehicle, force_only, fixed, slow
        self.idx = np.flatnonzero(prep.test)
        self.s = prep.design_s.take(self.idx)
        self.y = prep.y[self.idx]
        self.w = weights(prep.sd)[self.idx]
        self.base = float(np.nanmean(self.w * self.y**2))
        half = (self.idx >= prep.pair_offset) if prep.pair_offset else np.zeros(len(self.idx), bool)
        self.group = prep.flight[self.idx] * 2 + half  # a window never joins the two cross-fitting halves

    def residual(self, named, theta) -> np.ndarray:
        return self.y - extended_prediction(self.prep, self.vehicle, named, theta, self.idx, self.force_only)

    def summed(self, r: np.ndarray) -> float:
        """The torque residual summed over the slow balance's horizon (what it judges on), in noise units."""
        sums, _ = slow_mod.window_sums(r[:, 3:6], self.group, self.slow["horizon"])
        return float(np.sum(sums**2 / np.nanmedian(self.prep.sd[self.idx, 3:6], axis=0) ** 2))

    def explained(self, named, theta, refit) -> dict:
        """Each effect's share of the held-out loss: the named set refitted without it, against the whole
        set; an effect the slow torque balance named (``fixed``), its share of the held-out torque
        residual summed over the balance's horizon, as it was judged."""
        resid = self.residual(named, theta)
        ext = float(np.nanmean(self.w * resid**2))
        out = {}
        for e in named:
            rest = [x for x in named if x != e]
            r_rest = self.y - predict(self.s, self.vehicle, rest, refit(rest) if rest else np.zeros(0),
                                      self.force_only)
            if e in self.fixed:
                out[e] = (self.summed(r_rest) - self.summed(resid)) / self.summed(self.y)
            else:
                out[e] = float((np.nanmean(self.w * r_rest**2) - ext) / self.base)
        return out


def unsupported(named, explained, y, resid, w, min_gain, resid_without) -> tuple[str, str] | None:
    """The named effect the held-out data do not support, and why; None if every one is.

    An effect whose held-out share is zero or less explains nothing there (the lowest such first).  A
    held-out axis the named set leaves worse than the nominal model, by more than ``min_gain`` of its
    loss and by more than the noise floor's variance (the weights' unit; below it, regressor noise the
    extended model adds on an axis the nominal model already fits to noise): the effect whose removal helps
    that axis most (two effects that cancel where the flight spends its time fit the training part's
    small differences, and the held-out part pays for it).
    """
    if not named:
        return None
    weak = min(named, key=lambda e: (explained[e], e))
    if explained[weak] <= EDGE:  # (a share within numerical noise of zero is none)
        return weak, f"it explains {100 * explained[weak]:.2g} % of the held-out residual"
    nominal, ext = np.nanmean(w * y**2, axis=0), np.nanmean(w * resid**2, axis=0)
    worse = np.flatnonzero([Margins().at_least(a, (1 + min_gain) * b, on_edge=True) and
                            Margins().at_least(a - b, 1.0, on_edge=True) for a, b in zip(ext, nominal)])
    if not worse.size:
        return None
    j = int(worse[np.argmax(ext[worse] / nominal[worse])])
    helps = {e: float(np.nanmean(w[:, j] * resid_without([x for x in named if x != e])[:, j] ** 2)) for e in named}
    e = min(helps, key=helps.get)
    return e, (f"with it the held-out {AXES_SAID[j]} residual is {ext[j] / nominal[j]:.3g} x the nominal model's "
               f"({helps[e] / nominal[j]:.3g} x without it)")


# An axis's residual variance must exceed the noise floor's by this fraction of it before the anatomy
# shares it out: the floor is an estimate, and a few per cent of it is within its own uncertainty.
ANATOMY_MIN_SIGNAL = 0.05


def anatomy(stats: BlockStats, s_test: Signals, y_test: np.ndarray, sd_test: np.ndarray, vehicle,
            candidates: list[str], force_only=()) -> dict:
    """Share of each axis's held-out residual variance that each candidate explains alone (fit on train).

    Net of the noise floor: a share of 1 would leave only noise.  Negative: it does worse than nothing.
    NaN for an axis at the noise floor: its residual variance exceeds the noise variance by less than
    ``ANATOMY_MIN_SIGNAL`` of it, so there is nothing above noise to share out (dividing by that
    difference would print noise as huge shares).
    """
    out = {}
    base = np.nanmean(y_test**2, axis=0)
    noise = np.nanmean(sd_test**2, axis=0)
    signal = base - noise
    above = signal > ANATOMY_MIN_SIGNAL * noise
    for e in candidates:
        pred = predict(s_test, vehicle, [e], fit(stats, [e]), force_only)
        gain = base - np.nanmean((y_test - pred) ** 2, axis=0)
        out[e] = np.divide(gain, signal, out=np.full(len(gain), np.nan), where=above).tolist()
    return out


def extended_effects(effects: list[dict]) -> list[dict]:
    return [{"name": e["name"], "parameters": e["parameters"]} for e in effects]


def _replay_all(states_list, measured_list, vehicle, effects, cfg, prep):
    """Replay each state table (a flight or a gap-free segment of one) on its own measured rows."""
    out = {"nominal": [], "extended": []}
    owner = flight_of(states_list)
    for i, (st, meas) in enumerate(zip(states_list, measured_list)):
        meas = on_stamps(meas, st["t"])
        models = (("nominal", vehicle.effects), ("extended", vehicle.effects + extended_effects(effects)))
        errs = thread_map(lambda m: replay_mod.replay(st, meas, vehicle, m[1], cfg.horizon_s), models)
        for (key, _), err in zip(models, errs):
            err["test"] = err["t"] >= prep.windows[owner[i]]["test"][0]
            err["flight"] = i
            out[key].append(err)
    res = {}
    for key in out:
        err = pd.concat(out[key], ignore_index=True)
        err["window"] = err["flight"] * 100000 + err["window"]
        # a window belongs to the test part when it starts there
        start_test = err.groupby("window")["test"].transform("first")
        res[key] = {"errors": err, "summary": replay_mod.summarise(err, cfg.horizon_s, start_test.to_numpy()),
                    "growth": replay_mod.growth(err[start_test.to_numpy()], cfg.horizon_s)}
    return res


def rollout_all(states_list, measured_list, vehicle, effects, prep: Prepared, horizon: int, max_input_gap: int,
                trim_s: float, hybrid=None) -> dict:
    """Multi-step rollout (qr.rollout) of the nominal and the extended model and the references, from the
    held-out starts of every state table (a flight or a gap-free segment of one): the spec's block."""
    from .. import rollout
    from ..rollout import pieces

    models = {"hold": "hold", "rate_frozen": ("rate_frozen", vehicle), "nominal": (vehicle, list(vehicle.effects)),
              "extended": (vehicle, list(vehicle.effects) + extended_effects(effects))}
    if hybrid is not None:  # the extended vehicle with its learned torque remainder
        models["hybrid"] = (hybrid, list(hybrid.effects))
    owner = flight_of(states_list)
    parts = []
    for i, (st, meas) in enumerate(zip(states_list, measured_list)):
        st, meas, keep = pieces(st, meas, trim_s)
        keep &= st["t"].to_numpy() >= prep.windows[owner[i]]["test"][0]
        if keep.any():
            parts.append(rollout.score(st, meas, horizon, max_input_gap, models, keep))
    pooled = rollout.pool(parts)
    return {"horizon": horizon, "part": "held-out",
            "models": {k: rollout.summary(*v) for k, v in pooled.items()}}


def summed_r2(prep: Prepared, y: np.ndarray, resid: np.ndarray, horizon: int) -> dict:
    """Share of the held-out residual the extended model explains, per axis: sample by sample, and summed
    over windows of ``horizon`` samples (what a rollout integrates: a slow torque error held for the
    horizon), never across a segment's edge; windows holding a missing label are left out."""
    test = np.flatnonzero(prep.test)
    out = {"one_step": [], "summed": []}
    num1, den1 = np.nansum(resid**2, axis=0), np.nansum(y**2, axis=0)
    out["one_step"] = (1 - num1 / np.where(den1 > 0, den1, np.nan)).tolist()
    k = y.shape[1]
    sums, _ = slow_mod.window_sums(np.hstack([y, resid]), prep.flight[test], horizon)
    den, num = (sums[:, :k] ** 2).sum(axis=0), (sums[:, k:] ** 2).sum(axis=0)
    out["summed"] = (1 - num / np.where(den > 0, den, np.nan)).tolist()
    out["horizon"] = int(horizon)
    return out


def fit_torque_remainder(res: dict, vehicle, ridge: float) -> dict:
    """The learned torque remainder (qr.torque_remainder) on the training part, cross-fitted (features from
    one half-sample filter, labels from the other), and its held-out torque RMSE beside the extended one."""
    from .. import torque_remainder as trm

    fp = res["fitprep"]
    named, theta, fo = res["named"], res["theta"], res.get("force_only", ())
    tr = np.flatnonzero(fp.train)
    r_tr = fp.y[tr] - extended_prediction(fp, vehicle, named, theta, tr, fo)
    s_tr = fp.s.take(tr)
    W = trm.fit(trm.features(s_tr.v_b, s_tr.omega, s_tr.u, vehicle.hover_speed), r_tr[:, 3:6], ridge)
    te = np.flatnonzero(fp.test)  # cross-fitted too: a label's own rotor noise is not in its features
    s_te = fp.s.take(te)
    r_te = fp.y[te] - extended_prediction(fp, vehicle, named, theta, te, fo)
    hybrid = r_te[:, 3:6] - trm.features(s_te.v_b, s_te.omega, s_te.u, vehicle.hover_speed) @ W.T
    return {"weights": W, "ridge": ridge, "extended_torque_rmse": rms(r_te[:, 3:6]).tolist(),
            "hybrid_torque_rmse": rms(hybrid).tolist()}
