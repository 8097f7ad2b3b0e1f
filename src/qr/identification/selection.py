"""Which catalog effects are present: the selection policy, as small named steps: ``admissible`` (no two
effects the same term, no parameter on a plausibility bound, force and torque rows telling one story),
``search`` (the ``beam`` best admissible sets of each size, whole sets compared), ``choose_size`` (grow while
the held-out blocks say so), ``resolve_equivalents`` (the simplest of the sets the data cannot tell apart,
the others as ``confounded_with``); ``torque_arbitration`` before it.  docs/diagnose.md "How it decides".
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import ClassVar

import numpy as np

from ..allowed import check_fields, setting
from ..effects import CATALOG, TIED, with_unit
from .bootstrap import bootstrap
from .edge import EDGE, Margins, margin, rank_key
from .normal_equations import BlockStats, Columns, CrossValidator, at_bound, fit, solve

# Never named together (spec): the same term in force (gain = m/(m + dm)), and a C_T error is an
# all-equal motor imbalance in every row (the imbalance's drag-torque share, 1 + d_i - mean d, has no common
# mode), so a motor imbalance's mean is a mass error in force.
# J_z α_z = C_Q-torque makes a C_Q error an inertia error about z: named together their z parts would
# split one term arbitrarily.
SAME_TERM = (frozenset({"thrust_gain", "mass_error"}), frozenset({"thrust_gain", "motor_imbalance"}),
             frozenset({"mass_error", "motor_imbalance"}), frozenset({"yaw_torque_gain", "inertia_error"}))
# confounded whatever the data: an inertia error's z part is a C_Q error
PART_CONFOUNDED = {"inertia_error": ["yaw_torque_gain"]}
# Pairs that are the same term on some rows and differ only on others: a swap between them is judged
# on those rows alone (``rows`` statistics of ``select``).  A C_T and a mass error are the same in
# force, told apart by the roll/pitch torque a C_T error scales; J_z α_z = C_Q-torque makes a C_Q
# error an inertia error about z, told apart by the inertia error's roll and pitch parts.  On the rows
# where they are the same, the one fitted with the less noisy regressor (attitude rates rather than
# rotor speeds) wins by noise alone.
SWAP_ROWS = {frozenset({"thrust_gain", "mass_error"}): "torque",
             frozenset({"yaw_torque_gain", "inertia_error"}): "roll_pitch"}
ROWS = {"force": (0, 1, 2), "torque": (3, 4, 5), "roll_pitch": (3, 4)}


@dataclass
class SelectionConfig:
    """``diagnose.selection``; each field with its default and allowed values (the one place)."""

    KEY: ClassVar[str] = "diagnose.selection"
    folds: int = setting(5, "integer", ge=2)
    # an extra effect must cut the cross-validated loss by this fraction ...
    min_gain: float = setting(0.01, ge=0, lt=1)
    # ... in at least this share of the folds, and by min_gain in the median fold,
    min_fold_share: float = setting(0.8, ge=0, le=1)
    # ... or by this fraction, in most folds, with a paired per-block loss difference
    strong_gain: float = setting(0.05, ge=0, lt=1)
    # ... this many standard errors from zero
    t_gain: float = setting(2.0, gt=0)
    # sets of one size closer than min_gain and this many s.e. (paired, per block) are equivalent
    t_equivalent: float = setting(2.0, gt=0)
    beam: int = setting(12, "integer", ge=1)  # sets kept per size in the search
    # every effect of a named set must have a parameter this many s.e. (block bootstrap, joint fit) from
    # its neutral value: a pair that trades off along a direction the data barely constrain is not named
    t_name: float = setting(3.0, ge=0)
    check_bootstrap: int = setting(100, "integer", ge=10)
    # a set is inconsistent when its joint fit leaves the force or the torque rows this much (relative) ...
    consistency_rel: float = setting(0.05, ge=0)
    # ... and this many s.e. (per block) worse than their own fit
    consistency_t: float = setting(4.0, gt=0)
    max_effects: int = setting(6, "integer", ge=1)
    bootstrap: int = setting(200, "integer", ge=2)
    seed: int = setting(0, "integer", ge=0)

    def __post_init__(self):
        check_fields(self, lambda name: f"{self.KEY}.{name}", "src/qr/identification/selection.py")


@dataclass
class Selection:
    """What the selection decided, and the evidence for it."""

    named: list[str]
    confounded: dict[str, list[str]]
    path: list[dict] = field(default_factory=list)  # per size: best set, loss, gain, folds, decision
    equivalent: list[dict] = field(default_factory=list)  # sets of the chosen size as good as the named one
    rejected: dict = field(default_factory=dict)  # candidate -> why it could not be named alone
    loss_nominal: float = float("nan")
    loss_final: float = float("nan")


def simplicity(effects) -> tuple:
    """Order among equivalent sets: fewer free parameters first (tied effects share theirs), then catalog
    order."""
    effects = list(effects)
    shared = sum(len(CATALOG[g[0]].params) * (len(g) - 1) for g in TIED if set(g) <= set(effects))
    return sum(len(CATALOG[e].params) for e in effects) - shared, sorted(list(CATALOG).index(e) for e in effects)


def same_term(effects) -> bool:
    return any(pair <= set(effects) for pair in SAME_TERM)


def consistent(stats: BlockStats, row_stats, effects: list[str], cfg: SelectionConfig) -> str | None:
    """Effects acting on force AND torque must be told the same story by both.

    The joint fit of ``effects`` (all rows) must explain the force rows and the torque rows
    nearly as well as each group's own fit does: if one group's loss grows by more than
    ``consistency_rel`` of its own-fit loss, and the per-block growth is ``consistency_t``
    standard errors from zero, the physics of the shared effects does not explain the data,
    whatever the joint fit gains.  (Comparing losses, not parameters: in rows where an effect's
    signature is far below the noise, its own-rows estimate is attenuated by regressor noise but
    its loss hardly moves.)  Returns why, or None.
    """
    tied = {e for g in TIED if set(g) <= set(effects) for e in g}  # one term's force and moment (TIED)
    shared = [e for e in effects if (set(CATALOG[e].axes) & {0, 1, 2} and set(CATALOG[e].axes) & {3, 4, 5}
                                     or e in tied) and e not in stats.cols.force_only]
    if row_stats is None or not shared:
        return None
    idx = stats.cols.index(effects)
    theta = fit(stats, effects)
    for name, st in zip(("force", "torque"), row_stats):
        own = fit(st, effects)
        G, h, s = st.G[:, idx][:, :, idx], st.h[:, idx], st.s
        per_block = lambda th: s - 2 * h @ th + np.einsum("i,bij,j->b", th, G, th)  # noqa: E731
        joint, alone = per_block(theta), per_block(own)
        d = (joint - alone) / np.maximum(st.n, 1.0)
        grow = float((joint.sum() - alone.sum()) / max(alone.sum(), 1e-300))
        t = float(d.mean() / max(d.std(ddof=1) / np.sqrt(len(d)), 1e-300)) if len(d) > 2 else 0.0
        m = Margins()  # on the edge: inconsistent (not named)
        if m.at_least(grow, cfg.consistency_rel, on_edge=True) and m.at_least(t, cfg.consistency_t, on_edge=True):
            cols = Columns.of(effects)
            show = "; ".join(f"{e}: " + ", ".join(
                f"{p} = {with_unit(e, p, v + n)}" for p, v, n in zip(CATALOG[e].params, own[cols.slices[e]],
                                                                 CATALOG[e].neutral))
                for e in shared)
            return (f"force and torque disagree: fitted together, the {name} rows' residual grows by "
                    f"{100 * grow:.0f} % over their own fit ({show})")
    return None


@lru_cache(maxsize=None)
def wald_limit(t: float, k: int) -> float:
    """The chi-square quantile of the two-sided normal tail beyond ``t``, for ``k`` parameters (cached:
    the selection asks it a thousand times)."""
    from scipy.special import chdtri, ndtr  # chi2.isf's and norm.sf's own kernels: scipy.stats costs a
                                            # quarter second more
    return float(chdtri(k, 2 * ndtr(-t)))


def pinned_down(stats: BlockStats, effects: list[str], cfg: SelectionConfig) -> str | None:
    """Does the joint fit pin every effect down: its parameters jointly ``t_name`` s.e. from neutral?

    Two effects that are nearly the same column on this data (a C_T error and a constant body-z force
    while the thrust barely changes, on a 5 s flight) trade off: jointly fitted, both move far (a C_T
    of 0.5 against +0.12 N) with huge standard errors, while the joint loss barely beats either alone.
    The test is joint per effect (Wald, block-bootstrap covariance): a motor imbalance beside a body
    force has a poorly fixed common mode but a well fixed difference between rotors.
    """
    if len(effects) < 2 or cfg.t_name <= 0:
        return None
    theta = fit(stats, effects)
    reps = bootstrap(stats, effects, cfg.check_bootstrap, cfg.seed)
    cols = Columns.of(effects)
    for e in effects:
        sl = cols.slices[e]
        k = sl.stop - sl.start
        wald = float(theta[sl] @ np.linalg.pinv(np.atleast_2d(np.cov(reps[:, sl], rowvar=False)),
                                                 hermitian=True) @ theta[sl])
        limit = wald_limit(cfg.t_name, k)
        if not Margins().at_least(wald, limit, on_edge=False):
            return (f"not pinned down beside {', '.join(x for x in effects if x != e)}: jointly within "
                    f"{cfg.t_name:g} s.e. of no effect (Wald {wald:.1f} < {limit:.1f})")
    return None


# Two effects whose fitted terms leave less than this share of the smaller one's energy when added (their
# sum's amplitude below a third of it) cancel where the flight spends its time: the fit splits one
# term between them along a direction the data barely constrain (a mass error against a body-z force at
# hover), and the pair is one finding at most.
CANCEL = 0.1


def cancelling(stats: BlockStats, effects: list[str]) -> str | None:
    """Do two of ``effects``, fitted jointly, cancel each other (``CANCEL``)?  Energies are the
    weighted sums of squares of each term over the training data, from the normal equations."""
    if len(effects) < 2:
        return None
    theta = fit(stats, effects)
    cols = Columns.of(effects)
    G = stats.total[0]
    idx = {e: stats.cols.index([e]) for e in effects}
    th = {e: theta[cols.slices[e]] for e in effects}
    for i, a in enumerate(effects):
        for b in effects[i + 1:]:
            Ea = float(th[a] @ G[np.ix_(idx[a], idx[a])] @ th[a])
            Eb = float(th[b] @ G[np.ix_(idx[b], idx[b])] @ th[b])
            Eab = float(th[a] @ G[np.ix_(idx[a], idx[b])] @ th[b])
            small = min(Ea, Eb)
            if small > 0 and not Margins().at_least(Ea + Eb + 2 * Eab, CANCEL * small, on_edge=False):
                return (f"{a} and {b} cancel where the flight spends its time: fitted together, their terms "
                        f"add up to {100 * np.sqrt(max(Ea + Eb + 2 * Eab, 0) / small):.0f} % of the smaller one")
    return None


class Admissibility:
    """Step 1, cached per set: why a set of effects cannot be named together (None: it can)."""

    def __init__(self, stats: BlockStats, cfg: SelectionConfig, row_stats=None):
        self.stats, self.cfg, self.row_stats = stats, cfg, row_stats
        self._why: dict[tuple, str | None] = {}

    def __call__(self, effects) -> str | None:
        key = tuple(sorted(effects))
        if key not in self._why:
            self._why[key] = self._judge(list(key))
        return self._why[key]

    def _judge(self, effects):
        if same_term(effects):
            return "the same term as another named effect"
        if at_bound(self.stats, effects):
            return "a parameter sits on its plausibility bound"
        weak = pinned_down(self.stats, effects, self.cfg)
        if weak:
            return weak
        return cancelling(self.stats, effects) or consistent(self.stats, self.row_stats, effects, self.cfg)


def search(cv: CrossValidator, pool: list[str], admissible: Admissibility, cfg: SelectionConfig
           ) -> list[list[tuple[float, tuple]]]:
    """Step 2: per size k (index), the ``beam`` best admissible sets as ``(cv loss, effects)``, best first.

    Each size grows from the previous size's best sets, admissible or not: a set that cannot be named
    alone (a delay whose torque rows disagree while an inertia error is unmodelled) may be the core of
    one that can.
    """
    levels, grow_from = [[(cv.loss([]), ())]], [()]
    for _ in range(min(cfg.max_effects + 1, len(pool))):
        grown = {tuple(sorted(S + (c,))) for S in grow_from for c in pool if c not in S}
        # losses that tie to numerical noise are ordered by simplicity, then names: the same everywhere
        ranked = [(L, S) for _, _, L, S in sorted((rank_key(cv.loss(S)), simplicity(S), cv.loss(S), S)
                                                  for S in grown if not same_term(S))]
        keep = []
        for L, S in ranked:
            if admissible(S) is None:
                keep.append((L, S))
                if len(keep) == cfg.beam:
                    break
        if not keep:
            break
        levels.append(keep)
        grow_from = list(dict.fromkeys([S for _, S in ranked[:cfg.beam]] + [S for _, S in keep]))
    return levels


def better(cv: CrossValidator, new, old, cfg: SelectionConfig, margins: Margins | None = None) -> bool:
    """Does set ``new`` predict held-out blocks better than ``old`` by ``min_gain`` of the loss, and
    either consistently (in ``min_fold_share`` of the folds, by ``min_gain`` in the median fold: one
    fold cannot carry it) or strongly where it acts (by ``strong_gain``, in most folds, with a paired
    per-block t >= ``t_gain``: an effect confined to part of the flight, such as the kinematics of a
    marker during fast rotations, improves few blocks a lot and the others not at all)?"""
    m = margins if margins is not None else Margins()
    L_new, L_old = cv.loss(new), cv.loss(old)
    if not m.at_most(L_new, (1 - cfg.min_gain) * L_old, "the loss's gain against min_gain"):
        return False
    cur, trial = cv.losses(old), cv.losses(new)
    share = fold_share(cur, trial)  # a count of folds: compared exactly
    if share >= cfg.min_fold_share and \
            m.at_least(float(np.median((cur - trial) / cur)), cfg.min_gain, "the median fold's gain against min_gain"):
        return True
    return bool(m.at_most(L_new, (1 - cfg.strong_gain) * L_old, "the loss's gain against strong_gain")
                and share > 0.5
                and m.at_least(cv.paired_t(old, new), cfg.t_gain, "the paired t against t_gain"))


def fold_share(cur: np.ndarray, trial: np.ndarray) -> float:
    """Share of folds a trial set improves; a fold whose losses agree to numerical noise is not improved."""
    return float(np.mean([margin(c, t) > EDGE for c, t in zip(cur, trial)]))


def choose_size(cv: CrossValidator, levels, cfg: SelectionConfig) -> tuple[int, list[dict]]:
    """Step 3: grow while the best set one effect larger is ``better`` than the current best."""
    best = [lv[0] for lv in levels]
    margins = [Margins()] + [Margins() for _ in best[1:]]
    k, path = 0, []
    while k + 1 < len(best) and better(cv, best[k + 1][1], best[k][1], cfg, margins[k + 1]):
        k += 1
    for j, (L, S) in enumerate(best):
        ref = best[max(j - 1, 0)][0]
        cur, trial = cv.losses(best[max(j - 1, 0)][1]), cv.losses(S)
        judged = 0 < j <= k + 1  # the sizes whose step was decided
        path.append({"size": j, "effects": list(S), "loss": L, "gain": (ref - L) / ref if j else 0.0,
                     "fold_share": fold_share(cur, trial) if j else 1.0,
                     "t": cv.paired_t(best[j - 1][1], S) if j else 0.0,
                     "runner_up": list(levels[j][1][1]) if len(levels[j]) > 1 else None,
                     "runner_up_loss": levels[j][1][0] if len(levels[j]) > 1 else None,
                     "accepted": j <= k,
                     **({"margin": margins[j].closest, "on_edge": margins[j].on_edge} if judged else {})})
    return k, path


def swaps(effects) -> list[tuple[tuple, str]]:
    """``effects`` with one half of a ``SWAP_ROWS`` pair exchanged for the other, and the rows judging it."""
    out = []
    for pair, rows in SWAP_ROWS.items():
        for a in pair:
            (b,) = pair - {a}
            if a in effects and b not in effects:
                out.append((tuple(sorted([b if e == a else e for e in effects])), rows))
    return out


def resolve_equivalents(cv: CrossValidator, level, admissible, cfg: SelectionConfig, rows=None):
    """Step 4: the simplest of the sets the data cannot tell from the best; what each named effect is
    confounded with (the effects it can be swapped for).

    Sets that differ from the best by a ``SWAP_ROWS`` swap are judged on the rows where the pair
    differs (``rows``: their statistics), with the parameters the whole fit gives: equivalent when
    those rows do not prefer either by ``t_equivalent`` standard errors, else the preferred one.
    """
    L0, S0 = level[0]
    pool = dict((S, L) for L, S in level)
    judge = {S: r for S, r in swaps(S0) if set(S) <= set(cv.stats.cols.effects)} if rows else {}
    for S in judge:
        if S not in pool and admissible(S) is None:
            pool[S] = cv.loss(S)

    def t_swap(a, b):
        return cv.paired_t(a, b, on=rows[judge.get(a) or dict(swaps(a))[b]])

    m = Margins()  # on the edge, a set is equivalent: the simplest is named

    def equivalent(S, L):
        if S == S0:
            return True
        if S in judge:
            return m.at_most(abs(t_swap(S, S0)), cfg.t_equivalent, "a swap's t", on_edge=True)
        return m.at_most(L, (1 + cfg.min_gain) * L0, "equivalence's loss", on_edge=True) and \
            m.at_most(cv.paired_t(S, S0), cfg.t_equivalent, "equivalence's t", on_edge=True)

    eq = [(L, S) for S, L in pool.items() if equivalent(S, L)]
    L, chosen = min(eq, key=lambda x: (simplicity(x[1]), x[1]))
    # a swap the judging rows prefer significantly is not a matter of simplicity
    for S, _ in swaps(chosen) if rows else []:
        if S in pool and m.at_least(t_swap(chosen, S), cfg.t_equivalent, "a swap's t"):
            L, chosen = pool[S], S
    confounded = {e: [c for c in PART_CONFOUNDED.get(e, []) if c in cv.stats.cols.effects] for e in chosen}
    for _, S in eq:
        gone, new = set(chosen) - set(S), set(S) - set(chosen)
        if len(gone) == 1 and len(new) == 1:
            e, c = gone.pop(), new.pop()
            if c not in confounded[e]:
                confounded[e].append(c)
    equivalent_sets = [{"effects": list(S), "loss": Lx, "t": cv.paired_t(S, S0) if S != S0 else 0.0}
                       for Lx, S in eq if S != chosen]
    return list(chosen), {e: sorted(c, key=lambda x: simplicity([x])) for e, c in confounded.items()}, \
        equivalent_sets, L


def select(stats: BlockStats, cfg: SelectionConfig, rows: dict | None = None) -> Selection:
    """``rows``: statistics of the rows in ``ROWS`` alone (name -> BlockStats), for the consistency
    check and the judging of swaps; None: neither."""
    cv = CrossValidator(stats, cfg.folds)
    row_stats = (rows["force"], rows["torque"]) if rows else None
    admissible = Admissibility(stats, cfg, row_stats)
    pool = list(stats.cols.effects)
    rejected = {c: why for c in pool if (why := admissible((c,)))}
    levels = search(cv, pool, admissible, cfg)
    k, path = choose_size(cv, levels, cfg)
    sel = Selection([], {}, path=path, rejected=rejected, loss_nominal=levels[0][0][0], loss_final=levels[0][0][0])
    if k:
        named, confounded, equivalent, L = resolve_equivalents(cv, levels[k], admissible, cfg, rows)
        sel.named = sorted(named, key=lambda e: list(CATALOG).index(e))
        sel.confounded, sel.equivalent, sel.loss_final = confounded, equivalent, L
    return sel


@dataclass(frozen=True)
class Arbitration:
    """An effect the roll/pitch torque rows cannot arbitrate (:func:`torque_arbitration`): its force-row and
    (unbounded) torque-row estimates, given the torque effects the data contain."""

    force_rows: list[float]
    torque_rows: list[float]
    given: list[str]


def torque_arbitration(row_stats, base=(), effects=("thrust_gain",)) -> dict[str, Arbitration]:
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
        if at_bound(t_st, base + [e], e) and not at_bound(f_st, [e], e):
            G, h, _, _ = t_st.total
            idx = t_st.cols.index(base + [e])
            free = solve(G[np.ix_(idx, idx)], h[idx])[-len(CATALOG[e].params):]
            neutral = np.asarray(CATALOG[e].neutral, float)
            out[e] = Arbitration((fit(f_st, [e]) + neutral).tolist(), (free + neutral).tolist(), base)
    return out
