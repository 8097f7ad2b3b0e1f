"""The slow torque balance: an inertia error judged on the angular momentum over a rollout horizon.

Summed over ``H`` samples the inertia's regressor becomes ``Δω / dt`` (the noise of the twice-differentiated
attitude cancels): each roll/pitch entry of J is named on its own axis's summed residual, only where the
selection did not name ``inertia_error``.  The rule and why not yaw: docs/diagnose.md "How it decides".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..effects import CATALOG, plausible_bounds
from ..identification.bootstrap import block_counts

EFFECT = "inertia_error"
AXIS_NAMES = ("roll", "pitch", "yaw")
# the yaw entry is never tested (above): reported with this reason
NOT_TESTED = {2: "on the yaw axis the balance fixes only C_Q / J_zz, the term of yaw_torque_gain: not an inertia "
                 "it can tell apart"}


def window_sums(x: np.ndarray, group: np.ndarray, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """Sums of ``horizon`` consecutive rows of ``x`` (n, k) that share one ``group`` value (contiguous runs),
    and the index of each window's first row.  Windows holding a non-finite row are left out."""
    starts, sums = [], []
    edges = np.flatnonzero(np.diff(group)) + 1
    for run in np.split(np.arange(len(group)), edges):
        if run.size < horizon:
            continue
        a = x[run]
        bad = np.concatenate([[0], np.cumsum(~np.isfinite(a).all(axis=1))])
        c = np.vstack([np.zeros((1, a.shape[1])), np.cumsum(np.nan_to_num(a), axis=0)])
        ok = (bad[horizon:] - bad[:-horizon]) == 0
        sums.append((c[horizon:] - c[:-horizon])[ok])
        starts.append(run[:len(ok)][ok])
    if not sums:
        return np.zeros((0, x.shape[1])), np.zeros(0, dtype=int)
    return np.vstack(sums), np.concatenate(starts)


def per_block(x: np.ndarray, y: np.ndarray, block: np.ndarray, n_blocks: int) -> np.ndarray:
    """``(n_blocks, 3)``: Σx², Σxy, Σy² of each block's windows (one axis)."""
    out = np.zeros((n_blocks, 3))
    for j, v in enumerate((x * x, x * y, y * y)):
        out[:, j] = np.bincount(block, v, minlength=n_blocks)
    return out


def cv_gain(S: np.ndarray, folds: int) -> float:
    """Share of the summed residual a slope fitted on the other folds explains (blocks ``b % folds``)."""
    fold = np.arange(len(S)) % folds
    sse = 0.0
    for f in range(folds):
        tr = S[fold != f].sum(axis=0)
        k = tr[1] / tr[0] if tr[0] > 0 else 0.0
        te = S[fold == f].sum(axis=0)
        sse += te[2] - 2 * k * te[1] + k * k * te[0]
    total = S[:, 2].sum()
    return float(1 - sse / total) if total > 0 else 0.0


@dataclass(frozen=True)
class SlowAxis:
    """One inertia entry judged on its axis: the slope, its s.e., cross-validated gain and t, and whether it is
    named (why not); an axis not tested has no numbers."""

    axis: str
    parameter: str
    named: bool
    why_not: str | None
    estimate: float | None = None
    stderr: float | None = None
    cv_gain: float | None = None
    t: float | None = None

    def record(self) -> dict:
        if self.estimate is None:
            return {"axis": self.axis, "parameter": self.parameter, "named": self.named, "why_not": self.why_not}
        return {"axis": self.axis, "parameter": self.parameter, "estimate": self.estimate, "stderr": self.stderr,
                "cv_gain": self.cv_gain, "t": self.t, "named": self.named, "why_not": self.why_not}


@dataclass(frozen=True)
class SlowBalance:
    """The slow torque balance: the windows' horizon (samples) and count, each axis, and whether any is named."""

    horizon: int
    windows: int
    axes: list[SlowAxis]
    named: bool
    note: str = ""  # where the named set changed for it (qr.diagnose.fit: a C_T error swapped for a mass error)

    def record(self) -> dict:
        return {"horizon": self.horizon, "windows": self.windows, "axes": [a.record() for a in self.axes],
                "named": self.named, **({"note": self.note} if self.note else {})}


def slow_inertia(x: np.ndarray, y: np.ndarray, block: np.ndarray, n_blocks: int, bounds, folds: int,
                 t_name: float, min_gain: float, n_boot: int, seed: int, skip: dict | None = None) -> list[SlowAxis]:
    """Per axis: the slope of the summed residual ``y`` (n, 3) on the summed regressor ``x`` (n, 3), its
    cross-validated gain, block-bootstrap s.e. and whether it passes the rule; an axis in ``skip``
    (axis: why) is reported, not tested."""
    counts = block_counts(n_blocks, n_boot, seed)
    out = []
    for a in range(3):
        if skip and a in skip:
            out.append(SlowAxis(AXIS_NAMES[a], CATALOG[EFFECT].params[a], False, skip[a]))
            continue
        S = per_block(x[:, a], y[:, a], block, n_blocks)
        tot = S.sum(axis=0)
        est = float(tot[1] / tot[0]) if tot[0] > 0 else 0.0
        Sb = counts @ S
        draws = Sb[:, 1] / np.where(Sb[:, 0] > 0, Sb[:, 0], np.nan)
        used = int(np.count_nonzero(S[:, 0]))
        dof = np.sqrt(used / (used - 1)) if used > 2 else 1.0
        se = float(np.nanstd(draws, ddof=1) * dof)
        gain = cv_gain(S, folds)
        t = abs(est) / se if se > 0 else 0.0
        inside = bool(bounds[0][a] <= est <= bounds[1][a])
        ok = gain >= min_gain and t >= t_name and inside
        why = None if ok else ("is outside its plausible range" if not inside else
                               f"explains {100 * gain:.1f} % of the summed residual (< {100 * min_gain:g} %)"
                               if gain < min_gain else f"is only {t:.1f} s.e. from zero (< {t_name:g})")
        out.append(SlowAxis(AXIS_NAMES[a], CATALOG[EFFECT].params[a], ok, why, est, se, gain, t))
    return out


def slow_torque(prep, vehicle, residual: np.ndarray, horizon: int, folds: int, t_name: float,
                min_gain: float, n_boot: int, seed: int) -> SlowBalance:
    """The rule on the training rows of ``prep`` (cross-fitted: the regressor from the other half-sample
    filter), given ``residual`` (N, 6) left by the named effects on every row."""
    tr = np.flatnonzero(prep.train)
    half = (tr >= prep.pair_offset).astype(int) if prep.pair_offset else np.zeros(tr.size, dtype=int)
    # a window never spans two blocks, segments or cross-fitting halves
    group = (prep.block[tr] * 2 + half) * (int(prep.flight.max()) + 1) + prep.flight[tr]
    D = CATALOG[EFFECT].design(prep.design_s.take(tr), vehicle)
    own = np.stack([D[:, 3 + a, a] for a in range(3)], axis=1)
    sums, first = window_sums(np.hstack([own, residual[tr, 3:6]]), group, horizon)
    block = prep.block[tr][first]
    n_blocks = int(prep.block[tr].max()) + 1 if tr.size else 0
    lo, hi = plausible_bounds(EFFECT, vehicle)
    axes = slow_inertia(sums[:, :3], sums[:, 3:], block, n_blocks, (lo, hi), folds, t_name, min_gain, n_boot, seed,
                        NOT_TESTED) \
        if len(block) else []
    return SlowBalance(int(horizon), int(len(block)), axes, any(a.named for a in axes))
