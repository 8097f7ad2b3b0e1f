"""Physical parameters by simulation error: ``qr diagnose … diagnose.refine=rollout`` (issue 26).

The diagnosis estimates every parameter by equation error: the force and torque balance one sample at a
time (thesis eqs. 4.34, 4.39).  A simulator is judged by where it is half a second later
(docs/spec/evaluate.md).  Starting from the equation-error estimates, this module adjusts the named
effects' parameters and the vehicle's own coefficients — the inertia J (``inertia_error``), C_T
(``thrust_gain``), C_Q (``yaw_torque_gain``) and a pure delay (``actuator_delay``), each as its catalog
effect so that the one plant (:func:`qr.sim.plant.true_params`) gives it one meaning — to minimise the
evaluate protocol's multi-step error on the TRAINING windows, within the catalog's plausible bounds
(:func:`qr.effects.plausible_bounds`)::

    L(θ) = ½ Σ_windows Σ_h Σ_s ‖e_{s,h}(θ)‖² / (N ref_s²),   s ∈ {p, v, R, ω}

with ``e`` the rollout's error vectors of position, velocity, attitude (the rotation vector
2 sgn(w) vec(q_true⁻¹ ⊗ q̂), whose norm is 2 sin(angle/2), the protocol's angle to < 0.4 % below
0.3 rad) and body rate, ``ref_s`` the benchmark baseline's (``rate_frozen``) mean error over h on the
same windows (the signals on one scale), N the number of windows.  The rollout is the compiled one of
``qr evaluate`` (:func:`qr.sim.plant.rigid_body_rk4`: RK4 per log step, measured rotor speeds held, the
delay applied to the inputs); its Jacobian is by forward differences, every parameter's perturbed
rollouts of a window in one pass; the minimiser is Levenberg–Marquardt with the step solved within the
bounds (:func:`qr.identification.box_qp.box_qp`).

Standard errors: the Gauss–Newton covariance from that Jacobian, as a sandwich (``A⁻¹ B A⁻¹``, ``A = JᵀWJ``, B the long-run covariance of the windows' own gradients,
Bartlett weights over the windows starting within ``block_s``, at least 4 horizons, of each other):
neighbouring windows share samples, and a rollout's errors are correlated over the whole horizon, so
the textbook ``σ² A⁻¹`` would be far too small (its coverage on synthetic flights:
``tests/diagnose/test_refine.py``, ``benchmarks/refine_coverage.py``).  A parameter held at a bound has
none.

Errors in variables: noise in the logged rotor speeds makes a larger inertia look better (it filters
the noise the rollout integrates); the cost subtracts what the noise adds, rolling each window out again
on its inputs plus a realisation of their noise (:func:`_normal`).

Physical range: the plausible bounds; for the inertia the rigid-body limit J_ii ≤ m r² with r the
largest rotor distance (no mass beyond the rotors); for C_Q a propeller's torque-to-thrust ratio
(``KAPPA_PER_R``).  A parameter the rollout wants outside its range (or on a plausible bound), and a named
effect's parameter it wants beyond the one-step estimate's standard errors, is reported and held at its
equation-error value in a second fit of the others within their physical ranges: the written model
(:func:`refine`).  Deterministic: fixed chunks, fixed summation order (no dependence on the thread
count); the noise realisation is drawn from ``seed``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numba as nb
import numpy as np

from ..effects import CATALOG, TIED, plausible_bounds
from ..frames_compiled import qmul_s
from ..linalg_compiled import cholesky_solve
from ..rollout import QUANTITIES, RATE_FROZEN, MODEL, Windows, score_plant, summary, pool, at
from ..sim.plant import P_DELAY, P_MARKER, cg_from_tracked, rigid_body_rk4, tracked_pv, true_params

# the vehicle's own coefficients as catalog effects (their neutral value: the vehicle file's)
COEFFICIENTS = ("inertia_error", "thrust_gain", "yaw_torque_gain", "actuator_delay")
DISAGREE_Z = 2.0  # estimates this many combined standard errors apart disagree (two-sided 95 %)
CHUNKS = 16  # fixed, not the thread count: the order of every sum is the same anywhere
FD_STEP = 1e-4  # forward differences: this fraction of each parameter's scale
LABELS = {("inertia_error", "dJxx"): "J_xx", ("inertia_error", "dJyy"): "J_yy", ("inertia_error", "dJzz"): "J_zz",
          ("thrust_gain", "gain"): "C_T (gain)", ("yaw_torque_gain", "gain"): "C_Q (gain)",
          ("actuator_delay", "delay_s"): "delay (s)"}


@dataclass(frozen=True)
class RefineSettings:
    """What the refinement needs (``diagnose.refine_*`` and ``evaluate.horizon``; the windows are built
    with ``evaluate.max_input_gap`` before)."""

    horizon: int = 50  # H, steps of each window
    stride: int = 5  # every stride-th training start (neighbouring windows share H − stride steps)
    iterations: int = 30  # at most, Levenberg–Marquardt
    block_s: float = 2.0  # the covariance's bandwidth, s (at least 4 H steps)
    delay: bool = True  # a pure delay among the vehicle's coefficients
    exclude: tuple = ()  # effects never refined (diagnose.exclude: e.g. a thrust map fixed earlier)
    signal_weights: tuple = (1.0, 1.0, 1.0, 1.0)  # λ of p, v, R, ω in the loss


@dataclass(frozen=True)
class Parameter:
    """One refined parameter: its equation-error and rollout estimates and what was written."""

    effect: str
    name: str
    label: str
    named: bool  # a parameter of a named effect (else one of the vehicle's own coefficients)
    one_step: float  # the equation-error estimate (the vehicle file's value for a coefficient not named)
    one_step_se: float | None
    rollout: float  # the rollout's optimum within the plausible bounds
    rollout_se: float | None  # None at a bound or where not identified
    written: float  # into the vehicle file: the refined value, or the one-step value where out of range
    bounds: tuple[float, float]  # the optimisation's (plausible) bounds
    physical: tuple[float, float]  # its physical range
    bound_hit: str | None  # "lower" / "upper" when the rollout's optimum sits on a bound
    reference: float  # the vehicle's own value the parameter scales or adds to (J_ii for dJ; 1 for gains)
    followers: tuple = ()  # named effects that share this parameter (qr.effects.TIED: one rotor drag's moment)

    @property
    def in_range(self) -> bool:
        lo, hi = self.physical
        return bool(lo - 1e-12 * abs(lo) <= self.rollout <= hi + 1e-12 * abs(hi))

    @property
    def z(self) -> float | None:
        """The two estimates' difference in combined standard errors (None where the rollout has none)."""
        if self.rollout_se is None:
            return None
        s = math.hypot(self.rollout_se, self.one_step_se or 0.0)
        return (self.rollout - self.one_step) / s if s > 0 else None

    @property
    def disagree(self) -> bool:
        z = self.z
        return z is not None and abs(z) > DISAGREE_Z

    def total(self, x: float) -> float:
        """The physical quantity: J_ii + dJ for the inertia, else the parameter itself."""
        return self.reference + x if self.effect == "inertia_error" else x


@dataclass(frozen=True)
class Refinement:
    """What the refinement found (``diagnosis.json``'s ``refine`` block: :meth:`to_json`)."""

    parameters: tuple[Parameter, ...]
    windows: int  # training windows
    lag: int  # the covariance's bandwidth, in windows
    horizon: int
    stride: int
    iterations: int
    stopped: str
    loss_before: float  # L at the equation-error estimates (training windows)
    loss_after: float  # L of the written model
    loss_wanted: float  # L at the rollout's optimum (= loss_after when every value is in range)
    training: dict  # summary blocks (qr.rollout.summary) on the training windows: extended, refined, rate_frozen
    held_out: dict  # the same on the held-out windows
    wall_s: float
    not_candidates: dict = field(default_factory=dict)  # coefficient → why it was not refined

    def effects(self, named_effects: list[dict]) -> list[dict]:
        """The written model's effects: the named ones with their written values, then the vehicle's
        coefficients refined (only those that moved)."""
        out = []
        for e in named_effects:
            params = dict(e["parameters"])
            for p in self.parameters:
                if p.named and (p.effect == e["name"] or e["name"] in p.followers):
                    params[p.name] = p.written
            out.append({"name": e["name"], "parameters": params})
        names = [e["name"] for e in named_effects]
        for eff in COEFFICIENTS:
            ps = [p for p in self.parameters if p.effect == eff and not p.named]
            if ps and eff not in names and any(p.written != p.one_step for p in ps):
                params = dict(zip(CATALOG[eff].params, CATALOG[eff].neutral))
                params.update({p.name: p.written for p in ps})
                out.append({"name": eff, "parameters": params})
        return out

    def to_json(self) -> dict:
        H = self.horizon

        def ratios(blocks):
            ref = blocks["rate_frozen"]
            return {m: {q: (at(b, H, q) / at(ref, H, q) if at(b, H, q) is not None and at(ref, H, q) else None)
                        for q in QUANTITIES} for m, b in blocks.items() if m != "rate_frozen"}

        def mae(blocks):
            return {m: {q: at(b, H, q) for q in QUANTITIES} for m, b in blocks.items()}

        return {
            "method": "rollout",
            "loss": "L = 1/2 sum_windows sum_h sum_s |e_s,h|^2 / (N ref_s^2), s in p, v, R (rotation vector), w; "
                    "ref_s = rate_frozen's mean error over h on the training windows",
            "minimiser": "Levenberg-Marquardt within the plausible bounds, forward-difference Jacobian of the "
                         "compiled rollout",
            "covariance": f"Gauss-Newton sandwich, the windows' gradients' long-run covariance over {self.lag} "
                          "neighbouring windows (Bartlett weights)",
            "windows": self.windows, "horizon": H, "stride": self.stride, "iterations": self.iterations,
            "stopped": self.stopped, "wall_s": self.wall_s,
            "parameters": [{"effect": p.effect, "parameter": p.name, "label": p.label, "named": p.named,
                            **({"shared_with": list(p.followers)} if p.followers else {}),
                            "one_step": p.one_step, "one_step_stderr": p.one_step_se, "rollout": p.rollout,
                            "rollout_stderr": p.rollout_se, "written": p.written, "bounds": list(p.bounds),
                            "physical_range": list(p.physical), "reference": p.reference, "bound_hit": p.bound_hit, "in_range": p.in_range,
                            "z": p.z, "disagree": p.disagree} for p in self.parameters],
            "not_candidates": self.not_candidates,
            "training": {"loss_before": self.loss_before, "loss_after": self.loss_after,
                         "loss_wanted": self.loss_wanted, "ratio_to_rate_frozen_at_H": ratios(self.training),
                         "mae_at_H": mae(self.training)},
            "held_out": {"ratio_to_rate_frozen_at_H": ratios(self.held_out), "mae_at_H": mae(self.held_out),
                         "windows": int(self.held_out["rate_frozen"]["p"]["windows"]) if self.held_out else 0},
            "statements": statements(self),
        }


# ---- the compiled rollout: residuals, and the normal equations of their Jacobian -------------------

@nb.njit(cache=True)
def _window(t, X0, U, i, H, P, tp, tq, tv, tw, out, k, xs, xn, x):
    """The error vectors (H, 12) of the window starting at ``i`` (NaN rows where the truth is missing);
    False if the rollout diverged."""
    r = P[P_MARKER:P_MARKER + 3].copy()
    zero = np.zeros(3)
    x[:] = X0[i]
    cg_from_tracked(x, r)
    for h in range(1, H + 1):
        j = i + h
        u = U[j - 1]
        rigid_body_rk4(x, u, u, u, P, t[j] - t[j - 1], False, zero, k, xs, xn)
        for m in range(13):
            x[m] = xn[m]
        if not (abs(x[3]) + abs(x[4]) + abs(x[5]) < 1e3) or not math.isfinite(x[6]):
            return False
        px, py, pz, vx, vy, vz = tracked_pv(x, r)
        row = out[h - 1]
        for m in range(12):
            row[m] = 0.0
        if math.isfinite(tp[j, 0]):
            row[0], row[1], row[2] = px - tp[j, 0], py - tp[j, 1], pz - tp[j, 2]
        if math.isfinite(tv[j, 0]):
            row[3], row[4], row[5] = vx - tv[j, 0], vy - tv[j, 1], vz - tv[j, 2]
        if math.isfinite(tq[j, 0]):
            w, a, b, c = qmul_s(tq[j, 0], -tq[j, 1], -tq[j, 2], -tq[j, 3], x[6], x[7], x[8], x[9])
            s = 2.0 if w >= 0 else -2.0
            row[6], row[7], row[8] = s * a, s * b, s * c
        if math.isfinite(tw[j, 0]):
            row[9], row[10], row[11] = x[10] - tw[j, 0], x[11] - tw[j, 1], x[12] - tw[j, 2]
    return True


@nb.njit(cache=True, nogil=True)
def _normal(t, X0, Us, starts, lo, hi, tp, tq, tv, tw, H, Ps, uix, nix, dtheta, weight, A, Ad, g, gw, out):
    """Windows ``lo … hi−1``: ``out`` = [cost, windows dropped (diverged)]; with variants (``Ps[1 + k]``:
    parameter k moved by ``dtheta[k]``, forward differences) the Gauss–Newton ``A += JᵀWJ`` (lower
    triangle), ``g += JᵀWe`` and each window's own gradient in ``gw`` (its row).  ``Us[uix[v]]`` are the inputs of variant v (a
    delay moves them); ``starts``: the windows' first rows in the stacked arrays.

    With ``nix`` (not empty), the errors-in-variables correction: each variant is also rolled out on
    ``Us[nix[v]]`` (its inputs plus a realisation of their noise), ``d = x̂(u + δ) − x̂(u)``, and the cost
    is ``½ Σ w (e² − d²)``: ``E‖S δ‖²`` is what the input noise adds to ``E‖e‖²`` (S: the rollout's
    sensitivity to its inputs), and it falls as the inertia grows — uncorrected, the fit inflates J to
    filter the noise.  ``g`` is corrected alike; ``Ad`` gets ``J_dᵀWJ_d`` (the corrected Hessian is
    ``A − Ad``)."""
    p = dtheta.shape[0]
    K = Ps.shape[0]
    corr = nix.shape[0] > 0
    E = np.empty((K, H, 12))
    D = np.zeros((K, H, 12))
    Jw = np.empty((H * 12, p))
    Jd = np.zeros((H * 12, p))
    k4, xs, xn, x = np.empty((4, 13)), np.empty(13), np.empty(13), np.empty(13)
    for w_i in range(lo, hi):
        i = starts[w_i]
        ok = True
        for v in range(K):
            if not _window(t, X0, Us[uix[v]], i, H, Ps[v], tp, tq, tv, tw, E[v], k4, xs, xn, x):
                ok = False
                break
            if corr:
                if not _window(t, X0, Us[nix[v]], i, H, Ps[v], tp, tq, tv, tw, D[v], k4, xs, xn, x):
                    ok = False
                    break
                for h in range(H):
                    for m in range(12):
                        D[v, h, m] -= E[v, h, m]
        if not ok:
            out[1] += 1.0
            continue
        for h in range(H):
            for m in range(12):
                e = E[0, h, m]
                d = D[0, h, m]
                out[0] += 0.5 * weight[m // 3] * (e * e - d * d)
        if p == 0:
            continue
        for kk in range(p):
            for h in range(H):
                for m in range(12):
                    Jw[h * 12 + m, kk] = (E[1 + kk, h, m] - E[0, h, m]) / dtheta[kk]
                    if corr:
                        Jd[h * 12 + m, kk] = (D[1 + kk, h, m] - D[0, h, m]) / dtheta[kk]
        for a in range(p):
            s = 0.0
            for r_ in range(H * 12):
                wr = weight[(r_ % 12) // 3]
                s += wr * (Jw[r_, a] * E[0, r_ // 12, r_ % 12] - Jd[r_, a] * D[0, r_ // 12, r_ % 12])
            g[a] += s
            gw[w_i, a] = s
            for b in range(a + 1):
                s2 = 0.0
                s3 = 0.0
                for r_ in range(H * 12):
                    wr = weight[(r_ % 12) // 3]
                    s2 += Jw[r_, a] * wr * Jw[r_, b]
                    s3 += Jd[r_, a] * wr * Jd[r_, b]
                A[a, b] += s2
                Ad[a, b] += s3


# ---- the parameters --------------------------------------------------------------------------------

@dataclass
class _Spec:
    effect: str
    name: str
    named: bool
    start: float
    start_se: float | None
    lo: float
    hi: float
    phys_lo: float
    phys_hi: float
    scale: float
    reference: float
    followers: tuple = ()  # named effects that take this parameter too (TIED)


# A propeller's torque-to-thrust ratio κ = C_Q / C_T = (C_P / 2π C_T) D: fixed-pitch propellers have
# C_P / C_T of 0.3-1.0 at hover, and four rotors at a distance r that do not overlap have D < √2 r; the
# diameter is taken as at least r/2.  So κ lies between 0.3/2π · r/2 and 1.0/2π · √2 r.
KAPPA_PER_R = (0.3 / (2 * math.pi) * 0.5, 1.0 / (2 * math.pi) * math.sqrt(2))


def physical_range(effect: str, k: int, vehicle) -> tuple[float, float]:
    """Parameter k of ``effect``'s physical range: the plausible bounds; for the inertia also the
    rigid-body limit J_ii ≤ m r² (r: the largest rotor distance; no mass lies beyond the rotors), for C_Q's
    gain a propeller's torque-to-thrust ratio (``KAPPA_PER_R``)."""
    lo, hi = plausible_bounds(effect, vehicle)
    lo, hi = float(lo[k]), float(hi[k])
    r = float(np.max(np.hypot(*vehicle.rotors.positions.T)))
    if effect == "inertia_error":
        hi = min(hi, vehicle.mass * r * r - float(vehicle.inertia[k]))
    elif effect == "yaw_torque_gain":
        kappa = vehicle.torque_coeff / vehicle.thrust_coeff
        lo, hi = max(lo, KAPPA_PER_R[0] * r / kappa), min(hi, KAPPA_PER_R[1] * r / kappa)
    return lo, hi


def _specs(vehicle, effects: list[dict], settings: RefineSettings) -> tuple[list[_Spec], dict]:
    """The refined parameters: every named effect's, then the vehicle's coefficients not named (and not
    excluded, or confounded with a named effect)."""
    named = [e["name"] for e in effects]
    out, why = [], {}
    coeff = []
    for eff in COEFFICIENTS:
        if eff in named:
            continue
        if eff in settings.exclude:
            why[eff] = "excluded (diagnose.exclude: fixed by an earlier diagnosis)"
        elif eff == "thrust_gain" and {"mass_error", "motor_imbalance"} & set(named):
            why[eff] = f"confounded with the named {' and '.join(sorted({'mass_error', 'motor_imbalance'} & set(named)))}"
        elif eff == "actuator_delay" and not settings.delay:
            why[eff] = "not a candidate (diagnose.refine_delay=false)"
        else:
            coeff.append({"name": eff, "parameters": dict(zip(CATALOG[eff].params, CATALOG[eff].neutral)),
                          "stderr": {}})
    why["rotor_time_constant"] = ("not a candidate: the log's rotor signal is the measured rotor speed, which holds "
                                  "the rotor's own dynamics" if vehicle.rotor_input == "speed" else
                                  "not a candidate: the rollout drives the plant with the logged signal and has no "
                                  "rotor state (not implemented for motor commands)")
    # effects named with the one they are tied to (TIED) share its parameters: refined once, as that one's
    follows = {f: g[0] for g in TIED if set(g) <= set(named) for f in g[1:]}
    for e in [*effects, *coeff]:
        if e["name"] in follows:
            continue
        eff = CATALOG[e["name"]]
        lo, hi = plausible_bounds(e["name"], vehicle)
        for k, p in enumerate(eff.params):
            x = float(e["parameters"][p])
            se = (e.get("stderr") or {}).get(p)
            se = float(se) if se is not None and np.isfinite(se) else None
            plo, phi = physical_range(e["name"], k, vehicle)
            ref = float(vehicle.inertia[k]) if e["name"] == "inertia_error" else (1.0 if e["name"] in (
                "thrust_gain", "yaw_torque_gain") else 0.0)
            if e["name"] == "inertia_error":
                scale = float(vehicle.inertia[k])
            elif e["name"] in ("thrust_gain", "yaw_torque_gain"):
                scale = 1.0
            elif e["name"] == "actuator_delay":
                scale = 0.01
            else:
                width = float(hi[k] - lo[k]) if np.isfinite(hi[k] - lo[k]) else 0.0
                scale = max(abs(x), se or 0.0, 1e-3 * width, 1e-12)
            out.append(_Spec(e["name"], p, e in effects, min(max(x, float(lo[k])), float(hi[k])), se, float(lo[k]),
                             float(hi[k]), plo, phi, scale, ref,
                             tuple(f for f, lead in follows.items() if lead == e["name"])))
    return out, why


def _effects_of(specs: list[_Spec], theta: np.ndarray) -> list[dict]:
    d: dict = {}
    for s, x in zip(specs, theta):
        for e in (s.effect, *s.followers):
            d.setdefault(e, dict(zip(CATALOG[e].params, CATALOG[e].neutral)))[s.name] = float(x)
    return [{"name": e, "parameters": k} for e, k in d.items()]


# ---- the windows -------------------------------------------------------------------------------------

@dataclass
class _Stack:
    """The training windows of every piece stacked: one array per quantity, the starts as rows of it."""

    t: np.ndarray
    X0: np.ndarray
    U: np.ndarray
    tp: np.ndarray
    tq: np.ndarray
    tv: np.ndarray
    tw: np.ndarray
    starts: np.ndarray
    piece: np.ndarray  # per window: its piece (no window's errors are correlated with another piece's)
    lag: int  # windows: the covariance's bandwidth
    offsets: list  # per piece: (row offset, n)
    noise: np.ndarray | None = None  # a realisation of the rotor speeds' noise per row (None: no correction)

    def inputs(self, d: float, noisy: bool = False) -> np.ndarray:
        """The rotor speeds acting at every row for a delay ``d`` (each piece on its own stamps; ``noisy``:
        plus the noise realisation)."""
        from ..rollout import _delayed

        U = self.U + self.noise if noisy else self.U
        if d <= 0:
            return U
        out = np.empty_like(U)
        for o, n in self.offsets:
            out[o:o + n] = _delayed(self.t[o:o + n], U[o:o + n], d)
        return out


def _stack(pieces: list[Windows], H: int, stride: int, lag_s: float, noise=None, seed: int = 0) -> _Stack:
    """``noise``: per piece, the rotor speeds' noise (measured − filtered, (n, 4)); its realisation is it
    with a random sign per sample and rotor (``seed``): white, of the same size, independent of the
    window's own noise (measured − filtered alone is high-passed: it lacks the slow part of the noise,
    which the rollout integrates most)."""
    t, X0, U, tp, tq, tv, tw, starts, piece, offsets, nz = [], [], [], [], [], [], [], [], [], [], []
    o = 0
    rng = np.random.default_rng(seed)
    for k, w in enumerate(pieces):
        i = np.flatnonzero(w.ok)
        i = i[i + H < len(w.t)][::stride]
        n = len(w.t)
        offsets.append((o, n))
        if len(i):
            starts.append(i + o)
            piece.append(np.full(len(i), k))
        for acc, a in ((t, w.t), (X0, w.X0), (U, w.U), (tp, w.tp), (tq, w.tq), (tv, w.tv), (tw, w.tw)):
            acc.append(a)
        if noise is not None:
            d = np.nan_to_num(np.asarray(noise[k], float))
            nz.append(d * rng.choice([-1.0, 1.0], size=d.shape))
        o += n
    cat = lambda parts: np.ascontiguousarray(np.concatenate(parts))  # noqa: E731
    if not starts:
        from ..errors import QrInputError

        raise QrInputError(None, f"the training part holds no full {H}-step window to refine on",
                           "give longer flights, or a shorter evaluate.horizon")
    return _Stack(cat(t), cat(X0), cat(U), cat(tp), cat(tq), cat(tv), cat(tw), cat(starts).astype(np.int64),
                  cat(piece).astype(np.int64), max(1, int(np.ceil(lag_s / (stride * _median_dt(pieces))))), offsets,
                  cat(nz) if noise is not None else None)


def diagnosis_windows(states_list, measured_list, owner: list[int], windows: list[dict], horizon: int,
                      max_input_gap: int, trim_s: float) -> tuple[list[Windows], list[Windows], list[np.ndarray]]:
    """A diagnosis's training and held-out windows: per state table (a flight or a gap-free segment of
    one; ``owner``: its flight; ``measured_list``: its measured rows on the same stamps), the starts whose
    whole window lies in the flight's training part (``windows[f]["train"]``), those starting in its
    held-out part (as the diagnosis's rollout), and per training piece the rotor speeds' noise (measured
    less filtered)."""
    from ..rollout import pieces, windows as make_windows
    from ..states import ROTORS

    train, test, noise = [], [], []
    for st, meas, f in zip(states_list, measured_list, owner):
        st, meas, keep = pieces(st, meas, trim_s)
        t = st["t"].to_numpy(float)
        t_end = windows[f]["train"][1]
        ahead = np.concatenate([t[horizon:], np.full(min(horizon, len(t)), np.inf)])
        k_train = keep & (t >= windows[f]["train"][0]) & (ahead <= t_end)
        k_test = keep & (t >= windows[f]["test"][0])
        if k_train.any():
            w = make_windows(st, meas, horizon, max_input_gap, k_train)
            train.append(w)
            noise.append(w.U - st[ROTORS].to_numpy(float))
        if k_test.any():
            test.append(make_windows(st, meas, horizon, max_input_gap, k_test))
    return train, test, noise


# ---- the refinement ------------------------------------------------------------------------------------

def refine(train: list[Windows], held_out: list[Windows], vehicle, effects: list[dict],
           settings: RefineSettings = RefineSettings(), rotor_noise: list | None = None, seed: int = 0,
           log=lambda msg: None) -> Refinement:
    """Refine ``effects`` (the named effects: ``{name, parameters, stderr}``, the equation-error
    estimates) and the vehicle's coefficients on the ``train`` windows by the rollout's error; score the
    equation-error and the refined model on ``held_out``.  ``rotor_noise``: per training piece, the rotor
    speeds' noise (measured less filtered; None: no errors-in-variables correction); ``seed``: its
    realisation (see the module doc).

    Two fits.  The first moves every parameter within its plausible bounds: what the rollout wants, with
    standard errors.  The written model is a second fit, within the physical ranges: a parameter the
    rollout wants outside its physical range or on a plausible bound (it wants beyond it), or a named
    effect's parameter the rollout wants beyond its standard errors from the one-step estimate (the
    one-step fit measures that force or torque sample by sample; the rollout moving it is compensation for
    what the model lacks, said in the report), is held at its one-step value, the others fitted again.  If
    the written model does not lower the training loss below the one-step model's, the one-step model is
    written."""
    t0 = time.perf_counter()
    H = settings.horizon
    specs, why = _specs(vehicle, effects, settings)
    stack = _stack(train, H, settings.stride, max(settings.block_s, 4 * H * _median_dt(train)), rotor_noise, seed)
    weight = _weights(train, vehicle, H) * np.asarray(settings.signal_weights, float)
    fit = _Fit(stack, vehicle, specs, H, weight)
    theta0 = np.array([s.start for s in specs])
    log(f"refining {len(specs)} parameters on {len(stack.starts)} training windows of {H} steps")
    wanted, iters, stopped = fit.minimise(theta0, np.ones(len(specs), bool), settings.iterations)
    se = fit.stderr(wanted)
    params = []
    for k, s in enumerate(specs):
        hit = "lower" if wanted[k] <= s.lo + 1e-9 * s.scale else ("upper" if wanted[k] >= s.hi - 1e-9 * s.scale
                                                                   else None)
        params.append(Parameter(s.effect, s.name, _label(s), s.named, s.start, s.start_se, float(wanted[k]),
                                None if hit or not np.isfinite(se[k]) else float(se[k]), float(wanted[k]),
                                (s.lo, s.hi), (s.phys_lo, s.phys_hi), hit, s.reference, s.followers))
    held = np.array([not p.in_range or (p.bound_hit is not None and p.rollout != p.one_step) or (p.named and p.disagree)
                     for p in params])
    written = wanted
    if held.any():
        log("held at the one-step value in the written model: " + ", ".join(p.label for p, h in zip(params, held) if h))
        # the free ones within their physical ranges; a held one stays at its one-step value, even where the
        # diagnosis named it outside the range (said in the report; the refinement does not move it)
        start = np.where(held, theta0, wanted)
        phys = (np.where(held, np.minimum(theta0, [s.phys_lo for s in specs]), [s.phys_lo for s in specs]),
                np.where(held, np.maximum(theta0, [s.phys_hi for s in specs]), [s.phys_hi for s in specs]))
        written, more, stopped2 = fit.minimise(np.clip(start, *phys), ~held, settings.iterations, bounds=phys)
        iters += more
        stopped = f"{stopped}; the written model: {stopped2}"
    if fit.cost(written) >= fit.cost(theta0):  # no better than the one-step model on the training windows
        written = theta0
        stopped += "; the written model is the one-step one (what the refinement may write does not lower the loss)"
    from dataclasses import replace

    params = [replace(p, written=float(x)) for p, x in zip(params, written)]
    blocks_train = _blocks(train, vehicle, effects, specs, written, H)
    blocks_test = _blocks(held_out, vehicle, effects, specs, written, H) if held_out else {}
    return Refinement(tuple(params), len(stack.starts), stack.lag, H, settings.stride, iters, stopped,
                      fit.cost(theta0), fit.cost(written), fit.cost(wanted), blocks_train, blocks_test,
                      time.perf_counter() - t0, why)


def _label(s: _Spec) -> str:
    own = LABELS.get((s.effect, s.name)) or f"{s.effect}.{s.name}"
    return own + "".join(f" = {f}.{s.name}" for f in s.followers)


def _median_dt(pieces: list[Windows]) -> float:
    return float(np.median(np.concatenate([np.diff(w.t) for w in pieces])))


def _weights(train: list[Windows], vehicle, H: int) -> np.ndarray:
    """1 / ref_s² per signal: rate_frozen's mean error over h on the training windows."""
    P = true_params(vehicle, residual=False)
    s, c = pool([{"rf": score_plant(w, H, P, RATE_FROZEN)} for w in train])["rf"]
    with np.errstate(invalid="ignore", divide="ignore"):
        ref = np.nanmean(s / c, axis=0)
    ref = np.where(np.isfinite(ref) & (ref > 0), ref, 1.0)
    return 1.0 / ref**2


class _Fit:
    """The loss, its Gauss–Newton normal equations and the minimiser, in the scaled parameters θ / scale."""

    def __init__(self, stack: _Stack, vehicle, specs: list[_Spec], H: int, weight: np.ndarray):
        self.stack, self.vehicle, self.specs, self.H = stack, vehicle, specs, H
        self.weight = np.ascontiguousarray(weight / len(stack.starts))
        self.scale = np.array([s.scale for s in specs])
        self.lo = np.array([s.lo for s in specs])
        self.hi = np.array([s.hi for s in specs])

    def _plants(self, theta, moved=()):
        """The plant vectors of ``theta`` and of each parameter in ``moved`` moved forward by its step (back
        where the step would leave the bounds); the steps."""
        base = self.vehicle.effects
        P = lambda th: true_params(self.vehicle, base + _effects_of(self.specs, th), residual=False)  # noqa: E731
        Ps, steps = [P(theta)], []
        for k in moved:
            h = FD_STEP * self.scale[k]
            h = h if theta[k] + h <= self.hi[k] else -h
            th = theta.copy()
            th[k] += h
            Ps.append(P(th))
            steps.append(h / self.scale[k])
        return np.ascontiguousarray(np.array(Ps)), np.array(steps, float)

    def _run(self, Ps: np.ndarray, dtheta: np.ndarray):
        """Cost, ``A``, ``Ad``, ``g``, each window's gradient and windows dropped: CHUNKS fixed runs of windows on
        the threads (:func:`qr.parallel.thread_map`), added in their order."""
        from ..parallel import thread_map

        st = self.stack
        delays = Ps[:, P_DELAY]
        uniq = sorted(set(delays.tolist()))
        Us = [st.inputs(d) for d in uniq]
        uix = np.array([uniq.index(d) for d in delays], dtype=np.int64)
        nix = np.zeros(0, np.int64)
        if st.noise is not None:  # the same inputs plus their noise realisation (delayed alike)
            Us += [st.inputs(d, noisy=True) for d in uniq]
            nix = uix + len(uniq)
        Us = np.ascontiguousarray(np.array(Us))
        p, n = len(dtheta), len(st.starts)
        edges = np.linspace(0, n, CHUNKS + 1).astype(int)

        gw = np.zeros((n, p))  # each chunk writes its own rows

        def chunk(c):
            A, Ad, g, out = np.zeros((p, p)), np.zeros((p, p)), np.zeros(p), np.zeros(2)
            _normal(st.t, st.X0, Us, st.starts, edges[c], edges[c + 1], st.tp, st.tq, st.tv, st.tw, self.H, Ps,
                    uix, nix, np.ascontiguousarray(dtheta, float), self.weight, A, Ad, g, gw, out)
            return A, Ad, g, out

        parts = thread_map(chunk, range(CHUNKS))
        A, Ad, g, out = (sum((x[k] for x in parts[1:]), parts[0][k].copy()) for k in range(4))
        sym = lambda M: np.tril(M) + np.tril(M, -1).T  # noqa: E731
        return float(out[0]), sym(A), sym(Ad), g, gw, int(out[1])

    def cost(self, theta) -> float:
        Ps, _ = self._plants(theta)
        return self._run(Ps, np.zeros(0))[0]

    def normal(self, theta, moved):
        Ps, steps = self._plants(theta, moved)
        return self._run(Ps, steps)

    def minimise(self, theta0, free, iterations, bounds=None):
        """Levenberg–Marquardt on the ``free`` parameters, each step solved within the bounds (the plausible
        ones, or ``bounds``); stops when the loss falls by less than 1e-5 of itself (far below its sampling
        noise)."""
        from ..identification.box_qp import box_qp

        blo, bhi = bounds if bounds is not None else (self.lo, self.hi)
        theta = np.clip(theta0, blo, bhi)
        idx = np.flatnonzero(free)
        if not idx.size:
            return theta, 0, "nothing to refine"
        sc, lo, hi = self.scale[idx], blo[idx] / self.scale[idx], bhi[idx] / self.scale[idx]
        mu, it, stopped = 1e-3, 0, f"the iteration limit ({iterations})"
        while it < iterations:
            it += 1
            cost, A, Ad, g, _, _ = self.normal(theta, idx)
            H = _psd(A - Ad, A)
            z = theta[idx] / sc
            D = np.maximum(np.diag(H), 1e-12 * max(np.diag(H).max(), 1e-300))
            new = cost
            for _ in range(10):
                dz = box_qp(H + mu * np.diag(D), -g, lo - z, hi - z)
                trial = theta.copy()
                trial[idx] = np.clip((z + dz) * sc, blo[idx], bhi[idx])
                new = self.cost(trial)
                if new < cost:
                    theta = trial
                    mu = max(mu / 3, 1e-9)
                    break
                mu *= 4
            if not new < cost:
                stopped = "no step lowers the loss (a minimum)"
                break
            if cost - new <= 1e-5 * abs(cost):
                stopped = "converged (the loss fell by less than 1e-5 of itself)"
                break
        return theta, it, stopped

    def stderr(self, theta) -> np.ndarray:
        """Standard errors (parameter units) from the Gauss–Newton sandwich ``A⁻¹ B A⁻¹``, B the windows'
        gradients' long-run covariance (Bartlett weights over ``lag`` neighbouring windows of the same
        piece: overlapping windows share samples, and a rollout's errors stay correlated beyond its own
        horizon); NaN at a bound or where not identified."""
        at_bound = (theta <= self.lo + 1e-9 * self.scale) | (theta >= self.hi - 1e-9 * self.scale)
        idx = np.flatnonzero(~at_bound)
        se = np.full(len(theta), np.nan)
        if not idx.size:
            return se
        _, A, Ad, _, G, _ = self.normal(theta, idx)
        B = np.zeros((idx.size, idx.size))
        L = self.stack.lag
        for k in np.unique(self.stack.piece):  # pieces in order, lags in order: a fixed summation order
            Gk = G[self.stack.piece == k]
            B += Gk.T @ Gk
            for lag in range(1, min(L, len(Gk) - 1) + 1):
                C = Gk[:-lag].T @ Gk[lag:]
                B += (1.0 - lag / (L + 1.0)) * (C + C.T)
        p = idx.size
        Hm = np.ascontiguousarray(_psd(A - Ad, A))
        X, Lm, Y = np.empty((p, p)), np.empty((p, p)), np.empty((p, p))
        if not cholesky_solve(Hm, np.ascontiguousarray(B), Lm, X):
            return se
        cholesky_solve(Hm, np.ascontiguousarray(X.T), Lm, Y)  # A⁻¹ B A⁻¹ (B symmetric)
        se[idx] = np.sqrt(np.maximum(np.diag(Y), 0.0)) * self.scale[idx]
        return se


def _psd(H: np.ndarray, A: np.ndarray) -> np.ndarray:
    """The corrected Hessian where it is positive definite, else the uncorrected one (the correction is
    an estimate; subtracting it can leave a direction the data hardly inform with a negative curvature)."""
    from ..linalg_compiled import cholesky

    L = np.empty_like(H)
    return H if cholesky(np.ascontiguousarray(H), L) else A


def _blocks(pieces: list[Windows], vehicle, effects, specs, theta, H) -> dict:
    """Summary blocks (qr.rollout) of rate_frozen, the equation-error model and the refined one."""
    extended = [{"name": e["name"], "parameters": e["parameters"]} for e in effects]
    plants = {"rate_frozen": (true_params(vehicle, residual=False), RATE_FROZEN),
              "extended": (true_params(vehicle, vehicle.effects + extended, residual=False), MODEL),
              "refined": (true_params(vehicle, vehicle.effects + _effects_of(specs, theta), residual=False), MODEL)}
    parts = [{k: score_plant(w, H, P, mode) for k, (P, mode) in plants.items()} for w in pieces]
    return {k: summary(*v) for k, v in pool(parts).items()}


# ---- what it means, in words generated from the numbers ---------------------------------------------

def _g(x: float) -> str:
    return f"{x:.3g}"


def _ratio(p: Parameter, x: float) -> float | None:
    base = p.total(p.one_step)
    return p.total(x) / base if base else None


def statements(r: Refinement) -> list[str]:
    """Where the two estimates disagree beyond their standard errors, and what that means; what lies
    outside its physical range; what the refinement did on the training and the held-out windows."""
    out = []
    for p in r.parameters:
        ratio = _ratio(p, p.rollout)
        times = "" if ratio is None or p.effect == "actuator_delay" else (
            f" ({100 * (ratio - 1):+.2g} % of the one-step estimate)" if abs(ratio - 1) < 0.2 else
            f" (× {ratio:.3g} of the one-step estimate)")
        if not p.in_range:
            lo, hi = p.physical
            side = f"above its physical range (at most {_g(p.total(hi))}" if p.rollout > hi else \
                f"below its physical range (at least {_g(p.total(lo))}"
            why = {"inertia_error": ", the rigid-body limit m r²: no mass beyond the rotors",
                   "yaw_torque_gain": ", a propeller's torque-to-thrust ratio"}.get(p.effect, "")
            out.append(f"The rollout wants {p.label} = {_g(p.total(p.rollout))}{times}, {side}{why}); it is held at "
                       f"the one-step value {_g(p.total(p.one_step))} in the written model. " + _meaning(p, ratio, True))
        elif p.disagree:
            se = f" ± {_g(p.rollout_se)}" if p.rollout_se else ""
            se1 = f" ± {_g(p.one_step_se)}" if p.one_step_se else " (the vehicle file's, no standard error)"
            out.append(f"{p.label}: the rollout wants {_g(p.total(p.rollout))}{se}, the one-step fit "
                       f"{_g(p.total(p.one_step))}{se1}: {abs(p.z):.1f} standard errors apart{times}. "
                       + _meaning(p, ratio, False))
        elif p.bound_hit and p.total(p.rollout) == p.total(p.one_step):
            out.append(f"{p.label}: the rollout's optimum is the one-step value, its {p.bound_hit} bound "
                       f"{_g(p.total(p.rollout))}.")
        elif p.bound_hit:
            out.append(f"{p.label}: the rollout's optimum lies on its {p.bound_hit} plausible bound "
                       f"{_g(p.total(p.rollout))}{times}: it wants a value the catalog's range rules out; held at the "
                       f"one-step value {_g(p.total(p.one_step))} in the written model. " + _meaning(p, ratio, True))
    for p in r.parameters:
        lo, hi = p.physical
        if not lo <= p.written <= hi:
            out.append(f"{p.label} = {_g(p.total(p.written))}, the one-step estimate the diagnosis named, lies outside "
                       f"its physical range [{_g(p.total(lo))}, {_g(p.total(hi))}]; the refinement does not move it.")
    agree = [p.label for p in r.parameters if p.in_range and not p.disagree and not p.bound_hit and p.z is not None]
    if agree:
        out.append(f"Within {DISAGREE_Z:g} standard errors of each other: {', '.join(agree)}.")
    H = r.horizon
    for name, blocks in (("training", r.training), ("held-out", r.held_out)):
        if not blocks:
            continue
        ref = blocks["rate_frozen"]
        better = [q for q in QUANTITIES if at(blocks["refined"], H, q) is not None
                  and at(blocks["refined"], H, q) < at(blocks["extended"], H, q)]
        cells = ", ".join(f"{q} {at(blocks['extended'], H, q) / at(ref, H, q):.2f} → "
                          f"{at(blocks['refined'], H, q) / at(ref, H, q):.2f}" for q in QUANTITIES)
        out.append(f"On the {name} windows at h = {H} (ratio to rate_frozen, one-step → refined): {cells}; "
                   + (f"lower for {', '.join(better)}" if better else "lower for none")
                   + (f", higher for {', '.join(q for q in QUANTITIES if q not in better)}."
                      if len(better) < len(QUANTITIES) else "."))
    return out


def _meaning(p: Parameter, ratio: float | None, outside: bool) -> str:
    up = p.rollout > p.one_step
    if p.effect == "inertia_error":
        if up:
            return ("A larger inertia slows the rate response the rollout integrates: either the inertia is larger, "
                    "or the model lacks a torque that opposes the rate (a rate damping) or acts late (a rotor lag), "
                    "and the rollout fits it as inertia" + (" — outside the rigid-body range it cannot be an "
                                                            "inertia: it is a low-pass on a torque the model lacks."
                                                            if outside else "; the one-step fit, which sees the "
                                                            "angular acceleration itself, tells them apart."))
        return ("A smaller inertia speeds up the rate response: a torque the model underestimates, or body rates "
                "estimated late, fitted as inertia.")
    if p.effect == "thrust_gain":
        return ("The thrust that carries the trajectory over the horizon differs from the one-step force balance's: "
                "a thrust that depends on the flight state (inflow, ground effect), or a velocity or attitude error "
                "the rollout integrates, fitted as C_T.")
    if p.effect == "yaw_torque_gain":
        return ("The yaw response over the horizon differs from the one-step yaw torque balance: C_Q and Jzz enter "
                "only as their ratio, and a yaw-rate damping the model lacks is fitted as C_Q.")
    if p.effect == "actuator_delay":
        return ("A lag between the logged rotor speeds and the forces and torques they make, which the one-step fit "
                "does not see: rotor or logging latency, or start states (filtered estimates) that lag the truth."
                if up else "Less delay than the one-step fit found.")
    return (f"Over the horizon the {p.effect} parameter also absorbs what the model lacks there; the one-step value "
            "is what the force and torque balance measures sample by sample.")


# ---- the report's section ----------------------------------------------------------------------------

def report_lines(block: dict) -> list[str]:
    """``report.md``'s section on the refinement (from ``diagnosis.json``'s ``refine`` block)."""
    H = block["horizon"]
    lines = ["## Refinement by simulation error (`diagnose.refine=rollout`)", "",
             f"The named effects' parameters and the vehicle's own coefficients adjusted to minimise the "
             f"{H}-step rollout error on {block['windows']} training windows (every {block['stride']}th start), "
             f"from the one-step (equation-error) estimates; {block['iterations']} Levenberg–Marquardt iterations "
             f"({block['stopped']}), {block['wall_s']:.1f} s. Standard errors: {block['covariance']}.", "",
             "| parameter | one-step ± s.e. | rollout ± s.e. | z | physical range | written |",
             "|---|---:|---:|---:|---|---:|"]
    fmt = lambda x: "–" if x is None else f"{x:.4g}"  # noqa: E731
    for p in block["parameters"]:
        ref = p["reference"] if p["effect"] == "inertia_error" else 0.0
        lo, hi = p["physical_range"]
        total = lambda x: None if x is None else ref + x  # noqa: E731
        one = fmt(total(p["one_step"])) + (f" ± {p['one_step_stderr']:.2g}" if p["one_step_stderr"] else "")
        roll = fmt(total(p["rollout"])) + (f" ± {p['rollout_stderr']:.2g}" if p["rollout_stderr"] else
                                           (f" (at the {p['bound_hit']} bound)" if p["bound_hit"] else ""))
        lines.append(f"| {p['label']}{'' if p['named'] else ' (vehicle)'} | {one} | {roll} | "
                     f"{fmt(p['z']) if p['z'] is not None else '–'} | [{total(lo):.3g}, {total(hi):.3g}] | "
                     f"{fmt(total(p['written']))}{'' if p['in_range'] else ' (out of range: one-step kept)'} |")
    lines += ["", "Inertia rows are J (kg m²: the vehicle file's plus `inertia_error`'s dJ); gains are multiples of "
              "the file's C_T and C_Q; z: (rollout − one-step) / their combined standard error.", ""]
    for q in ("training", "held_out"):
        ratios = block[q]["ratio_to_rate_frozen_at_H"]
        if not ratios:
            continue
        lines += [f"{'Training' if q == 'training' else 'Held-out'} windows, ratio to `rate_frozen` at h = {H}:", "",
                  "| model | " + " | ".join(QUANTITIES) + " |", "|---|" + "---:|" * len(QUANTITIES)]
        for m, r in ratios.items():
            lines.append(f"| {m} | " + " | ".join(fmt(r[x]) for x in QUANTITIES) + " |")
        lines.append("")
    lines += [f"- {s}" for s in block["statements"]]
    for k, v in block.get("not_candidates", {}).items():
        lines.append(f"- {k}: {v}.")
    lines.append("")
    return lines


def refine_diagnosis(states_list, measured_list, windows: list[dict], vehicle, effects: list[dict], dcfg, ecfg,
                     seed: int = 0, log=lambda msg: None) -> Refinement:
    """The refinement of a diagnosis (``qr diagnose … diagnose.refine=rollout``) from plain inputs: its state
    tables (each a flight or a gap-free segment of one, ``attrs["flight"]``), their measured rows, the
    training/held-out times per flight (``windows``), the named effects with their equation-error
    parameters and standard errors, and the settings (``DiagnoseConfig``, ``EvaluateConfig``)."""
    from ..flight import on_stamps

    owner = [int(st.attrs.get("flight", i)) for i, st in enumerate(states_list)]
    measured = [on_stamps(m, st["t"]) for st, m in zip(states_list, measured_list)]
    train, held_out, noise = diagnosis_windows(states_list, measured, owner, windows, ecfg.horizon,
                                               ecfg.max_input_gap, dcfg.trim_s)
    settings = RefineSettings(horizon=ecfg.horizon, stride=dcfg.refine_stride,
                              iterations=dcfg.refine_iterations, block_s=dcfg.block_s, delay=dcfg.refine_delay,
                              exclude=tuple(dcfg.exclude))
    return refine(train, held_out, vehicle, effects, settings, noise, seed, log)
