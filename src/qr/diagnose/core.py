"""The algebra of a diagnosis on prepared labels (:mod:`.labels`): per-block normal equations of the
effects' designs, their predictions, the exact actuator delay, parameters in the catalog's units.

The steps of :func:`qr.diagnose.run` (:mod:`.fit`, :mod:`.held_out`) are built from these.
"""

from __future__ import annotations

from functools import reduce

import numpy as np

from ..effects import CATALOG, Signals, lookup, plausible_bounds
from ..identification import delay as delay_mod
from ..identification.normal_equations import (BlockStats, Columns, accumulate, bounded_noise, design, fit, loss,
                                                regressor_noise, row_sums)
from ..parallel import thread_map, workers
from .labels import Prepared, at_delay, exact_delay_term, weights
from .settings import DiagnoseConfig

AXES = ["fx", "fy", "fz", "tx", "ty", "tz"]
CHUNK = 20000
# Errors in variables: regressors from the other cross-fitting half carry their own noise, which
# attenuates slopes and favours whichever explanation uses the least noisy signal; the halves'
# regressor differences at the same stamps measure that noise, and it is taken out of XᵀWX.
EIV = True


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
    lb = np.concatenate([plausible_bounds(e, vehicle)[0] - lookup(e).neutral for e in cols.effects] + [[]])
    ub = np.concatenate([plausible_bounds(e, vehicle)[1] - lookup(e).neutral for e in cols.effects] + [[]])
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


def first_delay(prep: Prepared, vehicle, cfg: DiagnoseConfig) -> float:
    """A first estimate of an actuator delay, by the exact map alone on the training part.

    Other effects are slow next to the delay's signature (the rotor map's rate), so they barely move it.
    """
    w = weights(prep.sd)
    tr = np.flatnonzero(prep.train & np.isfinite(prep.y).all(axis=1))
    y, w = prep.y[tr], w[tr]
    return delay_mod.estimate(lambda d: float(np.sum(w * (y - exact_delay_term(prep, vehicle, d, tr)) ** 2)),
                              cfg.delay_max_s, 0.0)
