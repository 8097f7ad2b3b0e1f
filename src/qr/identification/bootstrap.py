"""Block bootstrap: resample whole blocks (contiguous ~2 s of data) with replacement.

Residuals of filtered data are correlated over a filter's time scale, not over
a block, so resampling blocks keeps that correlation and gives honest standard
errors.  Replicates are weights on the per-block normal equations (a block
drawn twice counts twice), so a replicate costs one small solve.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from .normal_equations import BlockStats, free_columns, solve_many, tie_map


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
    T = tie_map(effects)
    if T is None:
        return solve_many(Gb, hb, *stats.bounds(idx))
    # tied effects (TIED) share their parameters: solved for the free ones
    Gt = np.einsum("ji,njk,kl->nil", T, Gb, T)
    return solve_many(Gt, hb @ T, *stats.bounds(idx[free_columns(T)])) @ T.T


