"""Multi-step open-loop rollout: the field's yardstick (docs/spec/evaluate.md).

From the estimated state at every start sample ``i`` (position and velocity of the
tracked point in the world frame, attitude, body rate), a model driven by the
measured rotor speeds of samples ``i … i+H−1`` (zero-order hold, one RK4 step per
sample over the log's own step, quaternion renormalised) predicts samples ``i+1 … i+H``.  For each ``h``
the errors against the truth (measured position and attitude, estimated velocity
and rate) are summed over windows; a window adds to ``h`` only where the truth at
``i+h`` is present.  Sums and counts are returned, so flights pool by adding.

Models: a vehicle with its effects, integrated by the TRUE plant's rigid-body
kernel (``qr.sim.plant``: one meaning per effect everywhere), and two references on
the same windows: ``hold`` (the state held) and ``rate_frozen`` (the nominal rotor
thrust along body z, no drag, the body rate held at ω_i: the public
nanodrone-sysid-benchmark's physics baseline).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, ClassVar, TypeAlias

import numba as nb
import numpy as np

from .allowed import check_fields, check_known, setting
from .estimation.settings import DIAGNOSIS_FILTER
from .frames_compiled import quat_angle
from .holdout import SplitConfig
from .linalg_compiled import kernel_array
from .plant_state import N_P, N_RB, P_DELAY, P_MARKER, X_POS, X_QUAT, X_RATE, X_VEL
from .sim.plant import cg_from_tracked, rigid_body_rk4, rotor_speed_change, tracked_pv, true_params
from .states import POSITION, QUATERNION, RATE, ROTORS, VELOCITY

if TYPE_CHECKING:  # (annotations only: the config group's settings, read by every Hydra command, need no pandas)
    import pandas as pd

DEFAULTS_FILE = "src/qr/rollout.py"
QUANTITIES = ("p", "v", "R", "w")  # position (m), velocity (m/s), rotation angle (rad), body rate (rad/s)
REFERENCES = ("hold", "rate_frozen")  # the reference models every score is set beside
MODEL, HOLD, RATE_FROZEN = 0, 1, 2


STRIDE = 32
CHUNKS = 16  # fixed, not the thread count: the summation order (and so every digit) is the same anywhere


@nb.njit(cache=True, parallel=True, nogil=True)
def _rollout(t, X0, U, start_ok, tp, tq, tv, tw, H, P, mode, sums, counts):
    """Accumulate error sums (H, 4) and counts (H, 4) over every allowed start (chunks in parallel)."""
    part_s = np.zeros((CHUNKS, H, 4))
    part_c = np.zeros((CHUNKS, H, 4), dtype=np.int64)
    for c in nb.prange(CHUNKS):
        _starts(c, t, X0, U, start_ok, tp, tq, tv, tw, H, P, mode, part_s[c], part_c[c])
    for c in range(CHUNKS):
        sums += part_s[c]
        counts += part_c[c]


@nb.njit(cache=True)
def _finite(x):
    """``np.all(np.isfinite(x))`` without the temporary array (once per step of millions)."""
    for v in x:
        if not math.isfinite(v):
            return False
    return True


@nb.njit(cache=True)
def roll_window(t, X0, U, i, H, P, mode, r, out, k, xs, xn, x):
    """The window starting at ``i``: the predicted tracked point's p, v (world), q and ω after each step
    h = 1 … H into ``out[h − 1]`` (``N_RB`` values, the slots of a state); returns the number of steps made (fewer where the piece
    ends) and whether the rollout diverged.  The one rollout loop of ``qr evaluate``, the refinement and their references.

    ``mode``: MODEL, HOLD (the start state held) or RATE_FROZEN (ω held).  ``U[j − 1]`` acts over step
    j (zero-order hold); where the held speeds jump, the rotors' change of angular momentum goes to the body
    (:func:`qr.sim.plant.rotor_speed_change`, a plant with rotor inertia).  A rollout that diverges (a
    non-finite state or a speed of 1 km/s) is scored as the protocol scores it: its last sane state stands
    for the rest of the window."""
    n = X0.shape[0]
    zero = np.zeros(3)
    x[:] = X0[i]
    cg_from_tracked(x, r)
    moving = mode != HOLD
    steps = 0
    diverged = False
    p, v = X_POS.start, X_VEL.start
    for h in range(1, H + 1):
        j = i + h
        if j >= n:
            break
        if moving:
            u = U[j - 1]
            if h > 1 and mode == MODEL:
                rotor_speed_change(x, U[j - 2], u, P)
            rigid_body_rk4(x, u, u, u, P, t[j] - t[j - 1], mode == RATE_FROZEN, zero, k, xs, xn)
            if _finite(xn) and abs(xn[v]) + abs(xn[v + 1]) + abs(xn[v + 2]) < 1e3:
                x[:] = xn
            else:  # diverged: the last sane state stands for the rest (its errors still count)
                moving = False
                diverged = True
        px, py, pz, vx, vy, vz = tracked_pv(x, r)
        row = out[h - 1]
        row[p], row[p + 1], row[p + 2], row[v], row[v + 1], row[v + 2] = px, py, pz, vx, vy, vz
        for m in range(X_QUAT.start, N_RB):  # q, ω
            row[m] = x[m]
        steps = h
    return steps, diverged


@nb.njit(cache=True)
def _starts(c, t, X0, U, start_ok, tp, tq, tv, tw, H, P, mode, sums, counts):
    """Chunk ``c``: every CHUNKS-th run of STRIDE starts (the scored starts are often one end of a
    flight, its held-out part: interleaving keeps the threads equally busy)."""
    n = X0.shape[0]
    r = P[P_MARKER].copy()
    x, xn, xs, k = np.empty(N_RB), np.empty(N_RB), np.empty(N_RB), np.empty((4, N_RB))
    out = np.empty((H, N_RB))
    p, v, q, w = X_POS.start, X_VEL.start, X_QUAT.start, X_RATE.start
    for i in range(n - 1):
        if (i // STRIDE) % CHUNKS != c or not start_ok[i]:
            continue
        steps, _ = roll_window(t, X0, U, i, H, P, mode, r, out, k, xs, xn, x)
        for h in range(1, steps + 1):
            j = i + h
            y = out[h - 1]
            if np.isfinite(tp[j, 0]):
                sums[h - 1, 0] += math.sqrt((y[p] - tp[j, 0]) ** 2 + (y[p + 1] - tp[j, 1]) ** 2
                                            + (y[p + 2] - tp[j, 2]) ** 2)
                counts[h - 1, 0] += 1
            if np.isfinite(tv[j, 0]):
                sums[h - 1, 1] += math.sqrt((y[v] - tv[j, 0]) ** 2 + (y[v + 1] - tv[j, 1]) ** 2
                                            + (y[v + 2] - tv[j, 2]) ** 2)
                counts[h - 1, 1] += 1
            if np.isfinite(tq[j, 0]):
                sums[h - 1, 2] += quat_angle(tq[j], y[X_QUAT])
                counts[h - 1, 2] += 1
            if np.isfinite(tw[j, 0]):
                sums[h - 1, 3] += math.sqrt((y[w] - tw[j, 0]) ** 2 + (y[w + 1] - tw[j, 1]) ** 2
                                            + (y[w + 2] - tw[j, 2]) ** 2)
                counts[h - 1, 3] += 1


def _delayed(t: np.ndarray, U: np.ndarray, d: float) -> np.ndarray:
    if d <= 0:
        return U
    return np.column_stack([np.interp(t - d, t, U[:, k]) for k in range(U.shape[1])])


def _held(U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Missing rotor speeds held at the last present value; the length of the gap each row sits in."""
    miss = ~np.isfinite(U).all(axis=1)
    idx = np.where(~miss, np.arange(len(U)), 0)
    np.maximum.accumulate(idx, out=idx)
    held = U[idx]
    run = np.zeros(len(U), dtype=np.int64)
    c = 0
    for i in range(len(U)):
        c = c + 1 if miss[i] else 0
        run[i] = c
    return held, run


def starts_allowed(run: np.ndarray, H: int, max_input_gap: int, keep: np.ndarray | None = None) -> np.ndarray:
    """Starts whose inputs i … i+H−1 have no gap longer than ``max_input_gap`` samples (``keep``: also)."""
    n = len(run)
    bad = (run > max_input_gap).astype(np.int64)
    c = np.concatenate([[0], np.cumsum(bad)])
    hi = np.minimum(np.arange(n) + H, n)
    ok = (c[hi] - c[np.arange(n)]) == 0
    return ok if keep is None else ok & keep


@dataclass(frozen=True)
class Windows:
    """One gap-free piece as the rollout reads it: start states, inputs and truth on the same stamps."""

    t: np.ndarray  # (n,) s
    X0: np.ndarray  # (n, N_RB) start states of the tracked point: p, v (world), q, ω (body)
    U: np.ndarray  # (n, 4) measured rotor speeds, a dropout held at the last present value
    ok: np.ndarray  # (n,) bool: the starts scored (inputs without a long gap, a finite start state, ``keep``)
    tp: np.ndarray  # (n, 3) truth: measured position (NaN where missing)
    tq: np.ndarray  # (n, 4) measured attitude
    tv: np.ndarray  # (n, 3) estimated velocity
    tw: np.ndarray  # (n, 3) estimated body rate

    def scored_at(self, starts: np.ndarray) -> "Windows":
        """The same piece with only ``starts`` scored."""
        keep = np.zeros(len(self.t), bool)
        keep[starts] = True
        return replace(self, ok=keep)

    def inputs(self, P: np.ndarray) -> np.ndarray:
        """The rotor speeds acting at each sample for the plant ``P`` (its actuator delay applied)."""
        return np.ascontiguousarray(_delayed(self.t, self.U, float(P[P_DELAY])))


def windows(states: pd.DataFrame, measured: pd.DataFrame, horizon: int, max_input_gap: int,
            keep: np.ndarray | None = None) -> Windows:
    """The piece's :class:`Windows` (``states``: the filtered estimate; ``measured``: the log on its stamps)."""
    X0 = states[POSITION + VELOCITY + QUATERNION + RATE].to_numpy(float)
    tp = measured[POSITION].to_numpy(float)
    tq = measured[QUATERNION].to_numpy(float)
    tq = np.where(np.isfinite(tq).all(axis=1, keepdims=True), tq, np.nan)
    tp = np.where(np.isfinite(tp).all(axis=1, keepdims=True), tp, np.nan)
    U, run = _held(measured[ROTORS].to_numpy(float))
    ok = starts_allowed(run, horizon, max_input_gap, keep) & np.isfinite(X0).all(axis=1)
    t, X0, tp, tq, tv, tw = (kernel_array(a) for a in (states["t"].to_numpy(float), X0, tp, tq,
                                                       states[VELOCITY].to_numpy(float), states[RATE].to_numpy(float)))
    return Windows(t, X0, U, ok, tp, tq, tv, tw)


def score(states: pd.DataFrame, measured: pd.DataFrame, horizon: int, max_input_gap: int,
          models: dict, keep: np.ndarray | None = None) -> dict:
    """Sums and counts per model (``{name: (sums (H, 4), counts (H, 4))}``) on one gap-free piece.

    Each RK4 step spans the log's own step between two samples (a jittery log is not resampled: the
    truth stays as measured, and on a uniform log this is the spec's fixed ``dt``).

    ``states``: the filtered estimate (start states, velocity and rate truth); ``measured``: the log on
    the same time stamps (position and attitude truth, rotor speeds).  ``models``: name → ``"hold"``,
    ``("rate_frozen", vehicle)`` or ``(vehicle, effects)``.  ``keep``: the starts to score (all).
    """
    w = windows(states, measured, horizon, max_input_gap, keep)
    out = {}
    for name, spec in models.items():
        if spec == "hold":
            P = np.zeros(N_P)  # nothing is integrated; no marker offset
            out[name] = score_plant(w, horizon, P, HOLD)
        elif spec[0] == "rate_frozen":  # the physics baseline: never a learned wrench
            out[name] = score_plant(w, horizon, true_params(spec[1], residual=False), RATE_FROZEN)
        else:
            out[name] = score_plant(w, horizon, true_params(*spec), MODEL)
    return out


def score_plant(w: Windows, horizon: int, P: np.ndarray, mode: int = MODEL) -> tuple[np.ndarray, np.ndarray]:
    """Sums and counts (H, 4) of the plant ``P`` on the windows ``w`` (``mode``: MODEL, HOLD, RATE_FROZEN)."""
    sums, counts = np.zeros((horizon, 4)), np.zeros((horizon, 4), dtype=np.int64)
    U = w.inputs(P) if mode == MODEL else w.U
    _rollout(w.t, w.X0, U, w.ok, w.tp, w.tq, w.tv, w.tw, horizon, P, mode, sums, counts)
    return sums, counts


def reference_mae(pieces: list[Windows], vehicle, horizon: int) -> np.ndarray:
    """``ref_s`` (4,): ``rate_frozen``'s mean MAE over h = 1 … H on the scored starts of ``pieces``, per
    quantity (NaN where no window holds that truth): the scale on which a rollout loss weighs p, v, R and ω
    (the refinement's and the rollout-trained residual's)."""
    P = true_params(vehicle, residual=False)
    s, c = pool([{"rf": score_plant(w, horizon, P, RATE_FROZEN)} for w in pieces])["rf"]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.nanmean(s / c, axis=0)


def pool(parts: list[dict]) -> dict:
    """Add the sums and counts of several pieces, model by model."""
    out = {}
    for part in parts:
        for name, (s, c) in part.items():
            if name in out:
                out[name] = (out[name][0] + s, out[name][1] + c)
            else:
                out[name] = (s.copy(), c.copy())
    return out


# the spec's block of one model (docs/spec/evaluate.md): quantity -> {"mae": per h, "simerr", "windows"}
RolloutBlock: TypeAlias = "dict[str, dict]"


def summary(sums: np.ndarray, counts: np.ndarray) -> RolloutBlock:
    """The spec's block per model: for each quantity the MAE per h (null where no window) and SimErr."""
    with np.errstate(invalid="ignore", divide="ignore"):
        mae = sums / counts
    out = {}
    for k, q in enumerate(QUANTITIES):
        m = mae[:, k]
        out[q] = {"mae": [None if not np.isfinite(x) else float(x) for x in m],
                  "simerr": float(np.nansum(m)) if np.isfinite(m).any() else None,
                  "windows": int(counts[0, k])}
    return out


def horizon_metrics(models: dict, H: int, prefix: str = "", ratios: bool = False) -> dict:
    """MLflow metrics of :func:`summary` blocks: each model's MAE at ``H`` per quantity
    (``{prefix}{model}.{q}_at_{H}``) and, with ``ratios``, its ratio to ``rate_frozen`` (``..._ratio``)."""
    out = {}
    for model, block in models.items():
        for q in QUANTITIES:
            x, ref = at(block, H, q), at(models["rate_frozen"], H, q) if "rate_frozen" in models else None
            if x is not None:
                out[f"{prefix}{model}.{q}_at_{H}"] = x
                if ratios and ref:
                    out[f"{prefix}{model}.{q}_ratio"] = x / ref
    return out


def at(block: dict, h: int, q: str):
    """MAE of quantity ``q`` at step ``h`` (1-based) from a :func:`summary` block (None if absent)."""
    m = block[q]["mae"]
    return m[h - 1] if 0 < h <= len(m) else None


# ---- settings (config group `evaluate`), the scored pieces of a segment, the Markdown table ----

def _checks() -> list[str]:
    from .conventions import CHECKS

    return list(CHECKS)


@dataclass
class BandsConfig:
    """``evaluate.bands``: the uncertainty band of each model that has a source (qr.bands)."""

    KEY: ClassVar[str] = "evaluate.bands"
    enabled: bool = True  # false: no bands (evaluation.json without the block `bands`)
    draws: int = setting(32, "integer", ge=2, le=10_000)  # parameter draws of a Monte Carlo band
    seed: int = setting(0, "integer", ge=0)  # their generator's seed

    def __post_init__(self):
        check_fields(self, lambda name: f"{self.KEY}.{name}", DEFAULTS_FILE)

    @classmethod
    def from_dict(cls, d) -> "BandsConfig":
        d = dict(d or {})
        check_known(cls.KEY, d, cls, DEFAULTS_FILE)
        return cls(**d)


@dataclass
class EvaluateConfig:
    KEY: ClassVar[str] = "evaluate"
    horizon: int = setting(50, "integer", ge=1, le=100_000)  # H: steps of the log's sample period
    # windows whose rotor speeds miss more than this many samples in a row are skipped
    max_input_gap: int = setting(2, "integer", ge=0)
    trim_s: float = setting(0.5, ge=0)  # filter start-up and end dropped from each flight (as qr diagnose's)
    # convention checks (qr.conventions) a user who knows the log better turns off, e.g. [rotor_layout]
    skip_checks: list[str] = setting(kind="names", names=_checks, default_factory=list)
    # the held-out protocol's split of a set's flights (qr.holdout: repeat | trajectory | speed)
    split: SplitConfig = field(default_factory=SplitConfig)
    # the flights the scored models were trained on: each window is checked against their envelope
    # (speed, tilt, rotor speeds, body rates; qr.envelope); empty: no check
    trained_on: list[str] = field(default_factory=list)
    # each model's uncertainty band (qr.bands): parameter draws or a residual ensemble, where known
    bands: BandsConfig = field(default_factory=BandsConfig)

    def __post_init__(self):
        if isinstance(self.split, dict):
            self.split = SplitConfig.from_dict(self.split)
        if isinstance(self.bands, dict):
            self.bands = BandsConfig.from_dict(self.bands)
        self.trained_on = [str(f) for f in (self.trained_on or [])]
        check_fields(self, lambda name: f"{self.KEY}.{name}", DEFAULTS_FILE)

    @classmethod
    def from_dict(cls, d: dict) -> "EvaluateConfig":
        d = {k: v for k, v in dict(d or {}).items() if k != "filter"}  # (filter: read by _compose)
        check_known(cls.KEY, d, cls, DEFAULTS_FILE)
        return cls(**d)


@dataclass
class EvaluateNode(EvaluateConfig):
    """The config group ``evaluate`` (structured; ``conf/evaluate/default.yaml`` selects it)."""

    filter: str = DIAGNOSIS_FILTER  # the estimate the windows start from (as qr diagnose's)


def pieces(states: pd.DataFrame, rows: pd.DataFrame, trim_s: float) -> tuple[pd.DataFrame, pd.DataFrame, np.ndarray]:
    """A segment's estimate, its measured rows on the same stamps, and the starts to score (trimmed)."""
    from .flight import on_stamps

    t = states["t"].to_numpy(float)
    meas = on_stamps(rows, t)
    keep = (t >= t[0] + trim_s) & (t <= t[-1] - trim_s)
    return states, meas, keep


def table(models: dict, H: int) -> list[str]:
    """Markdown rows: each model's MAE at h = 1, 10, H and SimErr, per quantity."""
    hs = [h for h in (1, 10, H) if h <= H]
    hs = sorted(set(hs))
    head = ["model"] + [f"{q}@{h}" for q in QUANTITIES for h in hs] + [f"SimErr {q}" for q in QUANTITIES]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" + "---:|" * (len(head) - 1)]
    fmt = lambda x: "–" if x is None else f"{x:.4g}"  # noqa: E731
    for name, block in models.items():
        cells = [fmt(at(block, h, q)) for q in QUANTITIES for h in hs]
        cells += [fmt(block[q]["simerr"]) for q in QUANTITIES]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines
