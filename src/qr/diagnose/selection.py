"""Which catalog effects are present: forward selection with blocked cross-validation.

Every catalog term is linear in its parameters, so the whole search runs on
per-block normal equations.  For blocks ``b`` (contiguous time, ~2 s) we keep
``G_b = Xᵀ W X``, ``h_b = Xᵀ W y``, ``s_b = yᵀ W y`` over all candidate columns;
any subset's least-squares fit on any set of blocks, and its loss on any other
set, are then a few small matrix operations.  ``W`` weighs each of the six
residual axes by the inverse noise variance, so the loss is in units of the
noise floor (≈ 1 when only noise is left).

Selection: start from the nominal model; add the effect whose cross-validated
loss gain is largest among the stable ones (it helps in most folds, and by
``min_gain`` in the median fold: one fold cannot carry it) while that gain
exceeds ``min_gain`` of the current loss.  A simpler candidate nested in the winner (the
winner's columns reproduce its term) with most of the winner's gain is tried
first; the winner's extra parameters must then earn their place on what is
left.  Effects nearly as good as the chosen one whose fitted terms are
collinear with it are *confounded*: the simplest of them is named, the others
reported in ``confounded_with`` and never named.  Candidates that sit on a
plausibility bound or whose force and torque rows disagree are set aside, and
judged again after each named effect (an unmodelled effect in one channel can
make another look inconsistent).  A backward pass drops effects later ones made
redundant.  Parameters are refit on all training blocks; standard errors come
from a block bootstrap.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..effects import CATALOG, Signals
from .settings import SelectionConfig  # the settings and their allowed values live in .settings


@dataclass
class Columns:
    """Where each candidate effect's parameters sit in the stacked design."""

    effects: list[str]
    slices: dict[str, slice]
    # effects whose torque half is left out (see ``torque_arbitration``)
    force_only: frozenset = frozenset()

    @classmethod
    def of(cls, effects, force_only=()):
        slices, j = {}, 0
        for e in effects:
            k = len(CATALOG[e].params)
            slices[e] = slice(j, j + k)
            j += k
        return cls(list(effects), slices, frozenset(force_only) & set(effects))

    @property
    def size(self) -> int:
        return sum(s.stop - s.start for s in self.slices.values())

    def index(self, effects) -> np.ndarray:
        return np.concatenate([np.arange(self.slices[e].start, self.slices[e].stop) for e in effects]) \
            if effects else np.zeros(0, dtype=int)


def design(s: Signals, vehicle, cols: Columns) -> np.ndarray:
    """Stacked design (N, 6, p) of all candidate effects."""
    if not cols.effects:
        return np.zeros((len(s), 6, 0))
    parts = []
    for e in cols.effects:
        X = CATALOG[e].design(s, vehicle)
        if e in cols.force_only:
            X = X.copy()
            X[:, 3:, :] = 0.0
        parts.append(X)
    return np.concatenate(parts, axis=2)


# Pairs that are the same term in force (spec: gain = m/(m + dm)); only roll/pitch torque tells them apart.
SAME_IN_FORCE = {frozenset({"thrust_gain", "mass_error"})}


def torque_arbitration(row_stats, base=(), effects=("thrust_gain",)) -> dict:
    """Can the roll/pitch torque rows speak for the torque half of ``effects``?

    A C_T error scales force and torque alike.  When the torque rows (given the
    torque effects in ``base``, those the data contain) put its gain on the plausibility bound while
    the force rows keep it inside, the measured roll/pitch torque is not the rotor
    map's torque by more than any plausible C_T error (wrong inertia, latency or
    smoothing of the attitude channel): those rows cannot arbitrate, and the effect
    is fitted on the force rows (where it is the same term as ``mass_error``,
    reported as confounded).  Returns per such effect the force-row and the
    (unbounded) torque-row estimates.
    """
    out = {}
    if row_stats is None:
        return out
    f_st, t_st = row_stats
    base = [b for b in base if set(CATALOG[b].axes) & {3, 4, 5}]  # what else acts on the torque rows
    for e in effects:
        if e not in t_st.cols.effects:
            continue
        if _at_bound(t_st, base + [e], e) and not _at_bound(f_st, [e], e):
            G, h, _, _ = t_st.subset(np.arange(len(t_st.s)))
            idx = t_st.cols.index(base + [e])
            free = solve(G[np.ix_(idx, idx)], h[idx])[-len(CATALOG[e].params):]
            neutral = np.asarray(CATALOG[e].neutral, float)
            out[e] = {"force_rows": (fit(f_st, [e]) + neutral).tolist(), "torque_rows": (free + neutral).tolist(),
                      "given": base}
    return out


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


def accumulate(X: np.ndarray, y: np.ndarray, w: np.ndarray, block_id: np.ndarray, n_blocks: int):
    """Add a chunk's contribution to per-block normal equations.

    ``X`` (N, 6, p), ``y`` (N, 6), ``w`` (N, 6) weights, ``block_id`` (N,) sorted.
    """
    p = X.shape[2]
    G = np.zeros((n_blocks, p, p))
    h = np.zeros((n_blocks, p))
    s = np.zeros(n_blocks)
    n = np.zeros(n_blocks)
    ok = np.isfinite(y).all(axis=1) & np.isfinite(X).all(axis=(1, 2))
    edges = np.flatnonzero(np.diff(block_id)) + 1
    for idx in np.split(np.arange(len(block_id)), edges):
        idx = idx[ok[idx]]
        if idx.size == 0:
            continue
        b = block_id[idx[0]]
        Xb = X[idx].reshape(idx.size * 6, p)
        wb = w[idx].reshape(-1)
        yb = y[idx].reshape(-1)
        Xw = Xb * wb[:, None]
        G[b] += Xb.T @ Xw
        h[b] += Xw.T @ yb
        s[b] += float(yb @ (wb * yb))
        n[b] += idx.size * 6
    return G, h, s, n


def solve(G: np.ndarray, h: np.ndarray, ridge: float = 1e-9, lb=None, ub=None) -> np.ndarray:
    """Least squares from normal equations (scaled, tiny ridge), within bounds if given."""
    if G.size == 0:
        return np.zeros(0)
    d = np.sqrt(np.maximum(np.diag(G), 1e-300))
    Gs = G / np.outer(d, d)
    Gs[np.diag_indices_from(Gs)] += ridge
    theta = np.linalg.solve(Gs, h / d) / d
    if lb is None or (np.all(theta >= lb) and np.all(theta <= ub)):
        return theta
    # bounded: min ||Lᵀ x - L⁻¹ h||² with G = L Lᵀ is the same quadratic
    from scipy.linalg import cho_factor, solve_triangular
    from scipy.optimize import lsq_linear

    L, _ = cho_factor(Gs, lower=True)
    L = np.tril(L)
    b = solve_triangular(L, h / d, lower=True)
    res = lsq_linear(L.T, b, bounds=(lb * d, ub * d), method="bvls")
    return res.x / d


def loss(G, h, s, n, theta) -> float:
    return float((s - 2 * theta @ h + theta @ G @ theta) / max(n, 1.0))


@dataclass
class Selection:
    named: list[str]
    confounded: dict[str, list[str]]
    steps: list[dict] = field(default_factory=list)
    rejected: dict = field(default_factory=dict)
    loss_nominal: float = float("nan")
    loss_final: float = float("nan")


class CrossValidator:
    def __init__(self, stats: BlockStats, folds: int):
        B = len(stats.s)
        self.stats = stats
        self.fold_of = np.minimum((np.arange(B) * folds) // max(B, 1), folds - 1)
        self.folds = folds
        # training blocks for fold f: not in f and not adjacent to it (filter smoothing correlates neighbours)
        self.train = []
        for f in range(folds):
            val = self.fold_of == f
            near = val | np.roll(val, 1) | np.roll(val, -1)
            self.train.append(np.flatnonzero(~near))

    def losses(self, effects) -> np.ndarray:
        """Validation loss per fold, and its weight, for a set of effects."""
        idx = self.stats.cols.index(effects)
        out = np.zeros(self.folds)
        for f in range(self.folds):
            G, h, _, _ = self.stats.subset(self.train[f])
            theta = solve(G[np.ix_(idx, idx)], h[idx], 1e-9, *self.stats.bounds(idx))
            Gv, hv, sv, nv = self.stats.subset(np.flatnonzero(self.fold_of == f))
            out[f] = loss(Gv[np.ix_(idx, idx)], hv[idx], sv, nv, theta)
        return out

    def weights(self) -> np.ndarray:
        return np.array([self.stats.n[self.fold_of == f].sum() for f in range(self.folds)])


def _r2(stats: BlockStats, winner: list[str], rival: str, base: list[str]) -> float:
    """How much of the winner's fitted term (given ``base``) the rival's columns reproduce."""
    G, h, _, _ = stats.subset(np.arange(len(stats.s)))
    cols = stats.cols
    wi = cols.index(base + winner)
    theta = solve(G[np.ix_(wi, wi)], h[wi])
    t = np.zeros(cols.size)
    t[wi] = theta
    t[cols.index(base)] = 0.0  # the winner's own contribution
    ri = cols.index([rival])
    Grr = G[np.ix_(ri, ri)]
    beta = solve(Grr, G[ri] @ t)
    total = t @ G @ t
    if total <= 0:
        return 0.0
    resid = total - 2 * beta @ (G[ri] @ t) + beta @ Grr @ beta
    return float(1 - resid / total)


def _separate(stats: BlockStats, base: list[str], winner: str, rival: str, cfg: SelectionConfig) -> str:
    """Can the data tell ``winner`` from a collinear ``rival``?  Fit both jointly, block-bootstrap.

    'winner' / 'rival': only that one's parameters are significant (|t| >= t_separate);
    'both': both are (both present); 'confounded': neither is on its own.
    """
    effects = base + [winner, rival]
    theta = fit(stats, effects)
    boot = bootstrap(stats, effects, cfg.separate_bootstrap, cfg.seed)
    se = boot.std(axis=0) + 1e-300
    cols = Columns.of(effects)
    t = {e: float(np.max(np.abs(theta[cols.slices[e]] / se[cols.slices[e]]))) for e in (winner, rival)}
    w, r = t[winner] >= cfg.t_separate, t[rival] >= cfg.t_separate
    if w and r:
        return "both"
    if w:
        return "winner"
    if r:
        return "rival"
    return "confounded"


def simplicity(name: str) -> tuple:
    """Order for naming one of a confounded group: fewer parameters first, then catalog order."""
    return len(CATALOG[name].params), list(CATALOG).index(name)


def _at_bound(stats: BlockStats, effects: list[str], effect: str) -> bool:
    """Does the fit of ``effects`` put a parameter of ``effect`` on its plausibility bound?"""
    if stats.lb is None:
        return False
    theta = fit(stats, effects)
    cols = Columns.of(effects)
    sl = cols.slices[effect]
    lb, ub = stats.bounds(stats.cols.index(effects))
    th, lo, hi = theta[sl], lb[sl], ub[sl]
    tol = 1e-6 * np.maximum(1.0, np.abs(np.where(np.isfinite(lo), lo, 0)) + np.abs(np.where(np.isfinite(hi), hi, 0)))
    return bool(np.any(th <= lo + tol) or np.any(th >= hi - tol))


def _inconsistent(row_stats, base: list[str], effect: str, cfg: SelectionConfig) -> str | None:
    """An effect acting on force AND torque must be told the same story by both.

    Fits its parameters (with ``base``) on the force rows alone and on the torque
    rows alone; a difference beyond ``consistency_t`` standard errors (block
    bootstrap) and ``consistency_rel`` of the larger value means the physics of
    this effect does not explain the data, whatever the joint fit gains.
    """
    from ..effects import CATALOG

    axes = set(CATALOG[effect].axes)
    if row_stats is None or effect in row_stats[0].cols.force_only or not (axes & {0, 1, 2}) or not (axes & {3, 4, 5}):
        return None
    effects = base + [effect]
    est = []
    for st in row_stats:
        th = fit(st, effects)
        se = bootstrap(st, effects, cfg.separate_bootstrap, cfg.seed).std(axis=0)
        sl = Columns.of(effects).slices[effect]
        est.append((th[sl], se[sl]))
    (tf, sf), (tt, stt) = est
    diff = np.abs(tf - tt)
    bad = (diff > cfg.consistency_t * np.sqrt(sf**2 + stt**2)) & (diff > cfg.consistency_rel * np.maximum(
        np.abs(tf), np.abs(tt)))
    if np.any(bad):
        eff = CATALOG[effect]
        show = lambda th: ", ".join(f"{p} = {v + n:.4g}" for p, v, n in zip(eff.params, th, eff.neutral))  # noqa: E731
        return f"its physics disagrees with itself: the force rows give {show(tf)}, the torque rows {show(tt)}"
    return None


def inflation(stats: BlockStats, current: list[str], new: str) -> dict:
    """Variance inflation of each named effect's parameters when ``new`` joins them: the largest
    ratio of ``diag((XᵀWX)⁻¹)`` with and without ``new``'s columns (1 = orthogonal to them)."""
    if not current:
        return {}
    G, _, _, _ = stats.subset(np.arange(len(stats.s)))
    i0, i1 = stats.cols.index(current), stats.cols.index(current + [new])
    ridge = lambda A: A + 1e-12 * np.trace(A) / len(A) * np.eye(len(A))  # noqa: E731
    v0 = np.diag(np.linalg.inv(ridge(G[np.ix_(i0, i0)])))
    v1 = np.diag(np.linalg.inv(ridge(G[np.ix_(i1, i1)])))[: i0.size]
    ratio = v1 / np.maximum(v0, 1e-300)
    cols = Columns.of(current)
    return {e: float(ratio[cols.slices[e]].max()) for e in current}


def trade_off(stats: BlockStats, current: list[str], new: str, cfg: SelectionConfig) -> list[str]:
    """Named effects that ``new`` trades off with: their parameter variance grows > ``vif_max``-fold
    and their estimates move by more than ``consistency_rel`` of their size when ``new`` joins.
    (Collinearity alone is not enough: with enough data both are still pinned down.)"""
    inflated = [e for e, v in inflation(stats, current, new).items() if v > cfg.vif_max]
    if not inflated:
        return []
    before, after = fit(stats, current), fit(stats, current + [new])
    c0, c1 = Columns.of(current), Columns.of(current + [new])
    out = []
    for e in inflated:
        b, a = before[c0.slices[e]], after[c1.slices[e]]
        if np.any(np.abs(a - b) > cfg.consistency_rel * np.maximum(np.abs(b), 1e-12)):
            out.append(e)
    return out


def stable(trial: np.ndarray, cur: np.ndarray, cfg: SelectionConfig) -> bool:
    """Per-fold validation losses with (``trial``) and without (``cur``) a candidate: does it help in
    most folds, and by ``min_gain`` in the median fold (not one fold carrying the average)?"""
    return bool(np.mean(trial < cur) >= cfg.min_fold_share and np.median((cur - trial) / cur) >= cfg.min_gain)


def forward_select(stats: BlockStats, cfg: SelectionConfig, must_not_name=(), row_stats=None) -> Selection:
    """``row_stats``: (force-rows-only, torque-rows-only) statistics for the consistency check."""
    cv = CrossValidator(stats, cfg.folds)
    wts = cv.weights()
    current: list[str] = []
    cur = cv.losses(current)
    sel = Selection([], {}, loss_nominal=float(cur @ wts / wts.sum()))
    pool = [e for e in stats.cols.effects if e not in must_not_name]
    sel.rejected = {}
    while pool and len(current) < cfg.max_effects:
        L = float(cur @ wts / wts.sum())
        # physically implausible or self-contradicting candidates are not named now; judged again
        # once more effects are named (an unmodelled effect in one channel can make another look
        # inconsistent: blade flapping's torque hides a C_T error's torque)
        usable = []
        for c in pool:
            why = ("a parameter sits on its plausibility bound"
                   if any(_at_bound(stats, current + [c], e) for e in current + [c])
                   else _inconsistent(row_stats, current, c, cfg))
            if why:
                sel.rejected[c] = why
            else:
                sel.rejected.pop(c, None)
                usable.append(c)
        pool_all, pool = pool, usable
        if not pool:
            break
        trial = {c: cv.losses(current + [c]) for c in pool}
        gain = {c: L - float(v @ wts / wts.sum()) for c, v in trial.items()}
        # the largest gain among the stable candidates (an unstable leader does not block a stable one)
        steady = [c for c in pool if stable(trial[c], cur, cfg)]
        best = max(steady or pool, key=gain.get)
        share = float(np.mean(trial[best] < cur))
        step = {"candidate": best, "gain": gain[best] / L, "fold_share": share, "loss": L,
                "fold_gains": ((cur - trial[best]) / cur).round(4).tolist(),
                "gains": {c: g / L for c, g in sorted(gain.items(), key=lambda kv: -kv[1])}}
        if gain[best] < cfg.min_gain * L or not stable(trial[best], cur, cfg):
            step["accepted"] = False
            sel.steps.append(step)
            break
        # nested parsimony: a simpler candidate whose term the winner's columns reproduce, with most of
        # the winner's gain, leads; the winner's extra parameters then have to earn their place on
        # what is left (it stays a candidate).  E.g. a C_T error (thrust along body z, ∝ T) before a
        # constant body-frame force whose x/y parts are something else.
        nested = [c for c in pool if c != best and simplicity(c) < simplicity(best)
                  and gain[c] >= cfg.nested_share * gain[best] and stable(trial[c], cur, cfg)
                  and _r2(stats, [c], best, current) >= cfg.confound_r2]
        if nested:
            winner, best = best, max(nested, key=lambda c: (gain[c], [-x for x in simplicity(c)]))
            step.update(candidate=best, gain=gain[best] / L, fold_share=float(np.mean(trial[best] < cur)),
                        fold_gains=((cur - trial[best]) / cur).round(4).tolist(), nested_in=winner)
        rivals = [c for c in pool if c != best and _r2(stats, [best], c, current) >= cfg.confound_r2]
        # force-identical to the winner while the torque cannot arbitrate: confounded by construction
        same = lambda a, b: frozenset({a, b}) in SAME_IN_FORCE and bool(stats.cols.force_only & {a, b})  # noqa: E731
        rivals += [c for c in pool if c != best and c not in rivals and same(best, c)]
        # parsimony: among collinear candidates, the simplest one explaining about as much
        near = [c for c in [best] + rivals if gain[best] - gain[c] < cfg.min_gain * L]
        chosen = min(near, key=simplicity)
        confounded = []
        for c in [best] + rivals:
            if c == chosen:
                continue
            if same(chosen, c) or _r2(stats, [chosen], c, current) >= 1 - 1e-6:  # c contains chosen, or same in force
                confounded.append(c)
                continue
            verdict = _separate(stats, current, chosen, c, cfg)
            if verdict == "rival":  # the data prefer c: the other is not needed (it stays a candidate)
                chosen = c
            elif verdict == "confounded":
                confounded.append(c)
        # collinear with an effect already named: fitted together, the two trade off along a direction
        # the data barely constrain (a C_T error against a constant body-z force on one short flight)
        traded = trade_off(stats, current, chosen, cfg)
        if traded:
            # the same term in another form: it replaces the named one if no richer and better on its own
            swap = next((e for e in traded if simplicity(chosen) <= simplicity(e)
                         and float(cv.losses([x for x in current if x != e] + [chosen]) @ wts / wts.sum()) < L), None)
            if swap is None:
                step.update(accepted=False, candidate=chosen, collinear_with=traded)
                sel.steps.append(step)
                for e in traded:
                    sel.confounded[e] = sel.confounded.get(e, []) + [chosen]
                sel.rejected[chosen] = (f"collinear with {', '.join(traded)} on this data (fitted together they "
                                        "trade off: its parameters move far and their variance grows "
                                        f"> {cfg.vif_max:g}-fold)")
                pool = [c for c in pool_all if c != chosen]
                continue
            current.remove(swap)  # the data prefer the new form (it leaves the pool, as a named effect would)
            sel.confounded.pop(swap, None)
            step["replaced"] = swap
        group = [chosen] + confounded + ([step["replaced"]] if "replaced" in step else [])
        step.update(accepted=True, named=chosen, confounded=confounded)
        sel.steps.append(step)
        current.append(chosen)
        sel.confounded[chosen] = confounded
        pool = [c for c in pool_all if c not in group]
        cur = cv.losses(current)
    # backward pass: drop what later effects made redundant
    changed = True
    while changed and len(current) > 1:
        changed = False
        L = float(cv.losses(current) @ wts / wts.sum())
        for e in list(current):
            rest = [x for x in current if x != e]
            Lr = float(cv.losses(rest) @ wts / wts.sum())
            if Lr - L < cfg.min_gain * Lr:
                current = rest
                sel.steps.append({"dropped": e, "loss_without": Lr, "loss_with": L})
                sel.confounded.pop(e, None)
                changed = True
                break
    sel.named = current
    sel.loss_final = float(cv.losses(current) @ wts / wts.sum())
    return sel


def fit(stats: BlockStats, effects: list[str], blocks=None) -> np.ndarray:
    blocks = np.arange(len(stats.s)) if blocks is None else blocks
    G, h, _, _ = stats.subset(blocks)
    idx = stats.cols.index(effects)
    return solve(G[np.ix_(idx, idx)], h[idx], 1e-9, *stats.bounds(idx))


def bootstrap(stats: BlockStats, effects: list[str], n: int, seed: int) -> np.ndarray:
    """Block-bootstrap replicates of the parameter vector (n, p_effects)."""
    rng = np.random.default_rng(seed)
    B = len(stats.s)
    idx = stats.cols.index(effects)
    Gs = stats.G[:, idx][:, :, idx]
    hs = stats.h[:, idx]
    counts = np.array([np.bincount(rng.integers(0, B, B), minlength=B) for _ in range(n)], dtype=float)
    Gb, hb = np.tensordot(counts, Gs, 1), counts @ hs
    if idx.size == 0:
        return np.zeros((n, 0))
    # all replicates at once (the same scaled, ridged solve as `solve`); bounded ones again one by one
    d = np.sqrt(np.maximum(np.einsum("nii->ni", Gb), 1e-300))
    Gn = Gb / (d[:, :, None] * d[:, None, :])
    Gn[:, np.arange(idx.size), np.arange(idx.size)] += 1e-9
    out = np.linalg.solve(Gn, (hb / d)[:, :, None])[:, :, 0] / d
    lb, ub = stats.bounds(idx)
    if lb is not None:
        for i in np.flatnonzero(np.any(out < lb, axis=1) | np.any(out > ub, axis=1)):
            out[i] = solve(Gb[i], hb[i], 1e-9, lb, ub)
    return out
