"""Block bootstrap: resample whole blocks (contiguous ~2 s of data) with replacement.

Residuals of filtered data are correlated over a filter's time scale, not over
a block, so resampling blocks keeps that correlation and gives honest standard
errors.  Replicates are weights on the per-block normal equations (a block
drawn twice counts twice), so a replicate costs one small solve.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from .box_qp import box_qp_many
from .normal_equations import BlockStats, positive_definite


@lru_cache(maxsize=64)
def block_counts(n_blocks: int, n: int, seed: int, group: int = 1) -> np.ndarray:
    """``(n, n_blocks)`` multiplicities of each block in each replicate; runs of ``group`` consecutive
    blocks are drawn together.  Cached (the selection asks the same draw for every candidate set), so
    read-only."""
    rng = np.random.default_rng(seed)
    g = max(n_blocks // group, 1)
    of = np.minimum(np.arange(n_blocks) // group, g - 1)
    counts = np.array([np.bincount(rng.integers(0, g, g), minlength=g) for _ in range(n)], dtype=float)
    out = counts[:, of]
    out.flags.writeable = False
    return out


def bootstrap(stats: BlockStats, effects: list[str], n: int, seed: int, counts: np.ndarray | None = None
              ) -> np.ndarray:
    """Block-bootstrap replicates of the parameter vector (n, p_effects), bounds applied."""
    idx = stats.cols.index(effects)
    counts = block_counts(stats.blocks, n, seed) if counts is None else counts
    if idx.size == 0:
        return np.zeros((len(counts), 0))
    Gs = stats.G[:, idx[:, None], idx[None, :]]
    hs = stats.h[:, idx]
    Gb, hb = np.tensordot(counts, Gs, 1), counts @ hs
    return solve_many(Gb, hb, *stats.bounds(idx))


def solve_many(Gb: np.ndarray, hb: np.ndarray, lb=None, ub=None) -> np.ndarray:
    """``solve`` for a stack of normal equations (n, p, p), (n, p): all at once, bounded ones one by one."""
    p = Gb.shape[1]
    diag = np.einsum("nii->ni", Gb)
    d = np.sqrt(np.maximum(diag, 1e-12 * np.maximum(np.abs(diag).max(axis=1, keepdims=True), 1e-300)))
    Gn = Gb / (d[:, :, None] * d[:, None, :])
    Gn[:, np.arange(p), np.arange(p)] += 1e-9
    low = np.linalg.eigvalsh(Gn)[:, 0]  # as `solve`: a direction lost to regressor noise is held at the floor
    for i in np.flatnonzero(low < 1e-6):
        Gn[i] = positive_definite(Gn[i])
    out = np.linalg.solve(Gn, (hb / d)[:, :, None])[:, :, 0] / d
    if lb is not None:
        rows = np.flatnonzero(np.any(out < lb, axis=1) | np.any(out > ub, axis=1))
        if rows.size:
            out[rows] = box_qp_many(Gn[rows], hb[rows] / d[rows], lb * d[rows], ub * d[rows],
                                    out[rows] * d[rows]) / d[rows]
    return out
