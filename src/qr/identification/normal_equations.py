"""Least squares on per-block normal equations: the algebra under effect identification.

Every catalog term is linear in its parameters, so the whole search runs on
per-block normal equations.  For blocks ``b`` (contiguous time, ~2 s) we keep
``G_b = Xᵀ W X``, ``h_b = Xᵀ W y``, ``s_b = yᵀ W y`` over all candidate columns;
any subset's least-squares fit on any set of blocks, and its loss on any other
set, are then a few small matrix operations.  ``W`` weighs each of the six
residual axes by the inverse noise variance, so a loss is in units of the
noise floor (≈ 1 when only noise is left).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..effects import TIED, Signals, lookup
from .box_qp import box_qp, box_qp_many, scaled_solve_many


@dataclass
class Columns:
    """Where each candidate effect's parameters sit in the stacked design."""

    effects: list[str]
    slices: dict[str, slice]
    # effects whose torque half is left out (see ``selection.torque_arbitration``)
    force_only: frozenset = frozenset()

    @classmethod
    def of(cls, effects, force_only=()):
        slices, j = {}, 0
        for e in effects:
            k = len(lookup(e).params)
            slices[e] = slice(j, j + k)
            j += k
        return cls(list(effects), slices, frozenset(force_only) & set(effects))

    @property
    def size(self) -> int:
        return sum(s.stop - s.start for s in self.slices.values())

    def index(self, effects) -> np.ndarray:
        return np.concatenate([np.arange(self.slices[e].start, self.slices[e].stop) for e in effects]) \
            if effects else np.zeros(0, dtype=int)


def tie_map(effects) -> np.ndarray | None:
    """``T`` (p, q): the q free parameters of ``effects`` onto their p columns (in ``Columns.of`` order) where
    effects of ``TIED`` named together share one parameter vector (θ = T φ); None where none are tied."""
    effects = list(effects)
    pairs = [g for g in TIED if set(g) <= set(effects)]
    if not pairs:
        return None
    cols = Columns.of(effects)
    follows = {}  # column -> the column whose parameter it shares
    for group in pairs:
        lead = cols.slices[group[0]]
        for other in group[1:]:
            for j, i in zip(range(cols.slices[other].start, cols.slices[other].stop), range(lead.start, lead.stop)):
                follows[j] = i
    free = [j for j in range(cols.size) if j not in follows]
    T = np.zeros((cols.size, len(free)))
    for c, j in enumerate(free):
        T[j, c] = 1.0
    for j, i in follows.items():
        T[j, free.index(i)] = 1.0
    return T


def free_columns(T: np.ndarray) -> np.ndarray:
    """The columns that carry each free parameter of a :func:`tie_map` (its first)."""
    return np.argmax(T, axis=0)


def design(s: Signals, vehicle, cols: Columns) -> np.ndarray:
    """Stacked design (N, 6, p) of all candidate effects."""
    if not cols.effects:
        return np.zeros((len(s), 6, 0))
    parts = []
    for e in cols.effects:
        X = lookup(e).design(s, vehicle)
        if e in cols.force_only:
            X = X.copy()
            X[:, 3:, :] = 0.0
        parts.append(X)
    return np.concatenate(parts, axis=2)


@dataclass
class BlockStats:
    """Per-block normal equations."""

    G: np.ndarray  # (B, p, p)
    h: np.ndarray  # (B, p)
    s: np.ndarray  # (B,)
    n: np.ndarray  # (B,) weighted sample-axis count
    cols: Columns
    lb: np.ndarray | None = None  # plausible parameter range (minus neutral values), per column
    ub: np.ndarray | None = None

    def bounds(self, idx):
        if self.lb is None:
            return None, None
        return self.lb[idx], self.ub[idx]

    def subset(self, blocks) -> tuple[np.ndarray, np.ndarray, float, float]:
        return self.G[blocks].sum(0), self.h[blocks].sum(0), float(self.s[blocks].sum()), float(self.n[blocks].sum())

    @cached_property
    def total(self) -> tuple[np.ndarray, np.ndarray, float, float]:
        """``subset`` of every block, summed once (the selection fits a thousand sets on it; the
        statistics are not changed after they are built)."""
        return self.subset(np.arange(self.blocks))

    @property
    def blocks(self) -> int:
        return len(self.s)


def accumulate(X: np.ndarray, y: np.ndarray, w: np.ndarray, block_id: np.ndarray, n_blocks: int, out=None):
    """A chunk's contribution to per-block normal equations, row by row: ``G`` (6, B, p, p), ``h``
    (6, B, p), ``s`` (6, B) for each of the six force/torque rows alone, and ``n`` (B,), the sample-axis
    count; added to ``out`` (zeros if None).  Any set of rows is then a sum (:func:`row_sums`): the
    force, torque and all-row statistics from one pass.

    ``X`` (N, 6, p), ``y`` (N, 6), ``w`` (N, 6) weights, ``block_id`` (N,) sorted.  A sample counts only
    where its label, design and weights are finite in every row.
    """
    p = X.shape[2]
    if out is None:
        out = (np.zeros((6, n_blocks, p, p)), np.zeros((6, n_blocks, p)), np.zeros((6, n_blocks)),
               np.zeros(n_blocks))
    G, h, s, n = out
    ok = np.isfinite(y).all(axis=1) & np.isfinite(X).all(axis=(1, 2)) & np.isfinite(w).all(axis=1)
    edges = np.flatnonzero(np.diff(block_id)) + 1
    for idx in np.split(np.arange(len(block_id)), edges):
        idx = idx[ok[idx]]
        if idx.size == 0:
            continue
        b = block_id[idx[0]]
        Xb = X[idx].transpose(1, 0, 2)  # (6, nb, p)
        wb, yb = w[idx].T, y[idx].T  # (6, nb)
        Xw = Xb * wb[:, :, None]
        G[:, b] += np.matmul(Xb.transpose(0, 2, 1), Xw)
        h[:, b] += np.matmul(Xw.transpose(0, 2, 1), yb[:, :, None])[:, :, 0]
        s[:, b] += np.einsum("rn,rn->r", yb, wb * yb)
        n[b] += idx.size * 6
    return out


def row_sums(per_row: np.ndarray, rows=None) -> np.ndarray:
    """The statistics of a set of rows (None: all six) from :func:`accumulate`'s per-row ones."""
    return per_row[list(range(6)) if rows is None else sorted(rows)].sum(axis=0)


def bounded_noise(G: np.ndarray, N: np.ndarray, keep: float = 0.1) -> np.ndarray:
    """``N`` (B, p, p) scaled per column so that ``G - N`` keeps at least ``keep`` of each column's
    variance over all blocks: a column that is mostly regressor noise is not corrected into nonsense."""
    g, n = np.einsum("bii->i", G), np.einsum("bii->i", N)
    c = np.ones_like(g)
    over = n > (1 - keep) * g
    c[over] = np.maximum((1 - keep) * g[over], 0.0) / n[over]
    r = np.sqrt(c)
    return N * r[None, :, None] * r[None, None, :]


def regressor_noise(D: np.ndarray, w: np.ndarray, block_id: np.ndarray, n_blocks: int,
                    out: np.ndarray | None = None) -> np.ndarray:
    """Per-row, per-block ``Σ Dᵀ W D`` (6, B, p, p) of design differences ``D`` (N, 6, p) between the
    cross-fitting halves at the same stamps: their regressor noise, to take out of ``G`` (errors in
    variables); added to ``out``."""
    p = D.shape[2]
    N = np.zeros((6, n_blocks, p, p)) if out is None else out
    ok = np.isfinite(D).all(axis=(1, 2)) & np.isfinite(w).all(axis=1)
    edges = np.flatnonzero(np.diff(block_id)) + 1
    for idx in np.split(np.arange(len(block_id)), edges):
        idx = idx[ok[idx]]
        if idx.size:
            Db = D[idx].transpose(1, 0, 2)  # (6, nb, p)
            N[:, block_id[idx[0]]] += np.matmul(Db.transpose(0, 2, 1), Db * w[idx].T[:, :, None])
    return N


def positive_definite(Gs: np.ndarray, floor: float = 1e-6) -> np.ndarray:
    """A unit-diagonal-scaled Gram matrix with its eigenvalues held at ``floor`` or above (unchanged when
    they already are): directions the regressor-noise correction emptied carry no information."""
    lam, V = np.linalg.eigh(Gs)
    if lam[0] >= floor:
        return Gs
    out = (V * np.maximum(lam, floor * max(lam[-1], 1.0))) @ V.T
    return (out + out.T) / 2


def solve(G: np.ndarray, h: np.ndarray, ridge: float = 1e-9, lb=None, ub=None) -> np.ndarray:
    """Least squares from normal equations (scaled, tiny ridge), within bounds if given.

    ``G`` corrected for regressor noise may lose definiteness where the noise dominates a direction;
    that direction is then held at its least-informative (ridge) value.
    """
    if G.size == 0:
        return np.zeros(0)
    diag = np.diag(G)
    d = np.sqrt(np.maximum(diag, 1e-12 * max(float(np.abs(diag).max()), 1e-300)))
    Gs = G / np.outer(d, d)
    Gs[np.diag_indices_from(Gs)] += ridge
    Gs = positive_definite(Gs)
    theta = np.linalg.solve(Gs, h / d) / d
    if lb is None or (np.all(theta >= lb) and np.all(theta <= ub)):
        return theta
    return box_qp(Gs, h / d, lb * d, ub * d, theta * d) / d


def solve_many(G: np.ndarray, h: np.ndarray, lb=None, ub=None, ridge: float = 1e-9) -> np.ndarray:
    """``solve`` for a stack of normal equations (n, p, p), (n, p): compiled, bounded ones one by one."""
    n, p = h.shape
    G, h = np.ascontiguousarray(G, float), np.ascontiguousarray(h, float)
    Gn, d, out = np.empty_like(G), np.empty_like(h), np.empty_like(h)
    ok = scaled_solve_many(G, h, ridge, 1e-6, Gn, d, out)
    for i in np.flatnonzero(~ok):  # as `solve`: a direction lost to regressor noise is held at the floor
        Gn[i] = positive_definite(Gn[i])
        out[i] = np.linalg.solve(Gn[i], h[i] / d[i]) / d[i]
    if lb is not None:
        rows = np.flatnonzero(np.any(out < lb, axis=1) | np.any(out > ub, axis=1))
        if rows.size:
            out[rows] = box_qp_many(Gn[rows], h[rows] / d[rows], lb * d[rows], ub * d[rows],
                                    out[rows] * d[rows]) / d[rows]
    return out


def loss(G, h, s, n, theta) -> float:
    return float((s - 2 * theta @ h + theta @ G @ theta) / max(n, 1.0))


def fit(stats: BlockStats, effects: list[str], blocks=None) -> np.ndarray:
    """Parameters (minus neutral values) of ``effects`` on ``blocks`` (all), within the plausible bounds."""
    G, h, _, _ = stats.total if blocks is None else stats.subset(blocks)
    idx = stats.cols.index(effects)
    T = tie_map(effects)
    if T is None:
        return solve(G[np.ix_(idx, idx)], h[idx], 1e-9, *stats.bounds(idx))
    lb, ub = stats.bounds(idx[free_columns(T)])
    return T @ solve(T.T @ G[np.ix_(idx, idx)] @ T, T.T @ h[idx], 1e-9, lb, ub)


def at_bound(stats: BlockStats, effects: list[str], effect: str | None = None) -> bool:
    """Does the fit of ``effects`` put a parameter (of ``effect``, or of any) on a plausibility bound?

    A bound at the neutral value (drag cannot be negative) is a constraint, not nonsense: a
    component fitted to it is absent.  Only a bound away from neutral counts.
    """
    if stats.lb is None or not effects:
        return False
    theta = fit(stats, effects)
    lo, hi = stats.bounds(stats.cols.index(effects))
    if effect is not None:
        sl = Columns.of(effects).slices[effect]
        theta, lo, hi = theta[sl], lo[sl], hi[sl]
    scale = np.maximum(np.abs(np.where(np.isfinite(lo), lo, 0)), np.abs(np.where(np.isfinite(hi), hi, 0)))
    tol = 1e-6 * np.maximum(scale, 1e-300)
    low = (theta <= lo + tol) & (np.abs(lo) > tol)
    high = (theta >= hi - tol) & (np.abs(hi) > tol)
    return bool(np.any(low | high))


def inflation(stats: BlockStats, effects: list[str]) -> np.ndarray:
    """Variance inflation of each parameter of ``effects`` fitted jointly: ``diag(C⁻¹)`` of the normal
    equations scaled to unit diagonal (1: orthogonal to the others; large: the data cannot tell it from
    a combination of them)."""
    idx = stats.cols.index(effects)
    if idx.size == 0:
        return np.zeros(0)
    G = stats.G.sum(0)[np.ix_(idx, idx)]
    T = tie_map(effects)
    if T is not None:  # tied effects: one parameter, the inflation of it
        G = T.T @ G @ T
    d = np.sqrt(np.maximum(np.diag(G), 1e-300))
    C = G / np.outer(d, d) + 1e-12 * np.eye(len(d))
    vif = np.diag(np.linalg.inv(C))
    return vif if T is None else T @ vif


class CrossValidator:
    """Blocked cross-validation: ``folds`` contiguous runs of blocks; a fold's model is fitted on the
    blocks that are neither in it nor adjacent to it (filter smoothing correlates neighbours)."""

    def __init__(self, stats: BlockStats, folds: int):
        B = stats.blocks
        self.stats = stats
        self.folds = folds
        self.fold_of = np.minimum((np.arange(B) * folds) // max(B, 1), folds - 1)
        self.train = []
        for f in range(folds):
            val = self.fold_of == f
            near = val | np.roll(val, 1) | np.roll(val, -1)
            self.train.append(np.flatnonzero(~near))
        sums = [stats.subset(t)[:2] for t in self.train]  # the same for every candidate set
        self._train_G, self._train_h = np.stack([g for g, _ in sums]), np.stack([h for _, h in sums])
        self._cache: dict[tuple, np.ndarray] = {}

    def block_losses(self, effects, on: BlockStats | None = None) -> np.ndarray:
        """Validation loss of each block (unnormalised: weighted squared residual sum), its fold's fit;
        ``on``: the same blocks' statistics of some rows only (fit on all rows, judged on those)."""
        key = (tuple(sorted(effects)), id(on))
        if key not in self._cache:
            st, ev = self.stats, on or self.stats
            idx = st.cols.index(list(key[0]))
            T = tie_map(key[0])
            if idx.size and T is not None:
                Gt = np.einsum("ji,fjk,kl->fil", T, self._train_G[:, idx[:, None], idx[None, :]], T)
                theta = solve_many(Gt, self._train_h[:, idx] @ T, *st.bounds(idx[free_columns(T)])) @ T.T
            elif idx.size:
                theta = solve_many(self._train_G[:, idx[:, None], idx[None, :]], self._train_h[:, idx],
                                   *st.bounds(idx))
            else:
                theta = np.zeros((self.folds, 0))
            th = theta[self.fold_of]  # each block's fold's fit
            out = ev.s - 2 * np.einsum("bi,bi->b", ev.h[:, idx], th) + np.einsum(
                "bi,bij,bj->b", th, ev.G[:, idx[:, None], idx[None, :]], th)
            self._cache[key] = out
        return self._cache[key]

    def losses(self, effects) -> np.ndarray:
        """Validation loss per fold (noise-variance units)."""
        raw = self.block_losses(effects)
        return np.array([raw[self.fold_of == f].sum() / max(self.stats.n[self.fold_of == f].sum(), 1.0)
                         for f in range(self.folds)])

    def loss(self, effects) -> float:
        """Validation loss over all folds (noise-variance units)."""
        return float(self.block_losses(effects).sum() / max(self.stats.n.sum(), 1.0))

    def paired_t(self, worse, better, on: BlockStats | None = None) -> float:
        """t statistic of the per-block loss difference ``worse - better`` (positive: ``worse`` is worse),
        judged on the rows of ``on`` (default: all)."""
        n = np.maximum((on or self.stats).n, 1.0)
        d = (self.block_losses(worse, on) - self.block_losses(better, on)) / n
        if len(d) < 3 or not np.any(d):
            return 0.0
        return float(d.mean() / max(d.std(ddof=1) / np.sqrt(len(d)), 1e-300))
