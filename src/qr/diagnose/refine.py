"""Physical parameters by simulation error: ``qr diagnose … diagnose.refine=rollout`` (issues 26, 33): the
equation-error estimates adjusted to minimise the evaluate protocol's multi-step error on the training windows.
The method (loss, admission, balance, unconstrained directions, errors in variables, standard errors, physical
ranges): docs/diagnose.md "Refinement by simulation error"."""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numba as nb
import numpy as np

from ..effects import CATALOG, DIMENSIONLESS, TIED, plausible_bounds, unit
from ..errors import QrInputError
from ..frames_compiled import qmul_s
from ..linalg_compiled import cholesky_solve
from ..rollout import (QUANTITIES, RATE_FROZEN, MODEL, BandsConfig, RolloutBlock, Windows, roll_window, score_plant,
                       summary, pool, at)
from ..plant_state import N_RB, P_DELAY, P_J, P_MARKER, P_MASS, X_POS, X_QUAT, X_RATE, X_VEL
from ..sim.plant import cg_from_tracked, plant_accels, tracked_point, true_params

if TYPE_CHECKING:
    from ..bands import Scale

# the vehicle's own coefficients as catalog effects (their neutral value: the vehicle file's)
COEFFICIENTS = ("inertia_error", "thrust_gain", "yaw_torque_gain", "actuator_delay", "motor_imbalance", "cg_offset")
# rotor and airframe properties the catalog has no term for, as vehicle keys (qr.vehicle.ROTOR_PROPERTIES):
# each rotor's yaw-torque gain, the rotors' inertia (gyroscopic moment, momentum exchange), and, with blade
# flapping named, its pitch coefficient over its roll one
PROPERTIES = ("rotor_torque_gains", "rotor_inertia", "flapping_pitch_ratio")
ROTOR_GAIN_RANGE = (0.7, 1.3)  # each rotor's C_Q beyond motor_imbalance's share (as its ±30 %)
FLAP_RATIO_RANGE = (0.5, 2.0)  # the pitch flapping coefficient over the roll one
ROTOR_MASS_SHARE = 0.05  # a rotor (bell and propeller) weighs at most this share of the vehicle
DISAGREE_Z = 2.0  # estimates this many combined standard errors apart disagree (two-sided 95 %)
CHUNKS = 16  # fixed, not the thread count: the order of every sum is the same anywhere
FD_STEP = 1e-4  # forward differences: this fraction of each parameter's scale
LABELS = {("inertia_error", "dJxx"): "J_xx", ("inertia_error", "dJyy"): "J_yy", ("inertia_error", "dJzz"): "J_zz",
          ("thrust_gain", "gain"): "C_T (gain)", ("yaw_torque_gain", "gain"): "C_Q (gain)",
          ("actuator_delay", "delay_s"): "delay (s)", ("rotor_inertia", ""): "rotor inertia (kg m²)",
          ("flapping_pitch_ratio", ""): "flapping pitch/roll ratio",
          **{("rotor_torque_gains", str(i)): f"C_Q rotor {i + 1} (gain)" for i in range(8)},
          **{("motor_imbalance", f"d{i + 1}"): f"C_T, C_Q rotor {i + 1} (d{i + 1})" for i in range(8)},
          ("cg_offset", "rx"): "CG x (m)", ("cg_offset", "ry"): "CG y (m)"}


@dataclass(frozen=True)
class RefineSettings:
    """What the refinement needs (``diagnose.refine_*`` and ``evaluate.horizon``; the windows are built
    with ``evaluate.max_input_gap`` before)."""

    horizon: int = 50  # H, steps of each window
    stride: int = 5  # every stride-th training start (neighbouring windows share H − stride steps)
    iterations: int = 30  # at most, Levenberg–Marquardt
    block_s: float = 2.0  # the covariance's bandwidth, s (at least 4 H steps)
    delay: bool = True  # a pure delay among the vehicle's coefficients
    rotors: bool = True  # per-rotor C_T and C_Q gains, the CG, the rotors' inertia, the flapping pitch/roll ratio
    beyond: str = "bound"  # a parameter wanted beyond its physical range: "hold" (one-step value), "bound" or "auto"
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
    refined: bool = True  # False: a term the held-out windows did not admit (left at its one-step value)
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

    def to_json(self) -> dict:
        """The parameter as ``diagnosis.json``'s ``refine.parameters`` states it."""
        return {"effect": self.effect, "parameter": self.name, "label": self.label, "named": self.named,
                **({"shared_with": list(self.followers)} if self.followers else {}),
                "one_step": self.one_step, "one_step_stderr": self.one_step_se, "rollout": self.rollout,
                "rollout_stderr": self.rollout_se, "written": self.written, "bounds": list(self.bounds),
                "physical_range": list(self.physical), "reference": self.reference, "bound_hit": self.bound_hit,
                "in_range": self.in_range, "z": self.z, "disagree": self.disagree, "refined": self.refined}


@dataclass(frozen=True)
class Direction:
    """A parameter combination the data cannot fix: a near-null direction of the rollout loss's Hessian
    (in units of each parameter's physical range), its standard error along it in those units."""

    loadings: tuple  # ((label, weight), …): the unit direction's parts of |weight| ≥ 0.1, largest first
    curvature: float  # its eigenvalue over the largest one
    stderr: float | None  # along the direction, in physical ranges (None: numerically null)

    def to_json(self) -> dict:
        return {"parameters": {k: w for k, w in self.loadings}, "curvature_ratio": self.curvature,
                "stderr_in_ranges": self.stderr}

    def words(self) -> str:
        terms = " ".join(f"{'+' if w >= 0 else '−'} {abs(w):.2f} {k}" for k, w in self.loadings).lstrip("+ ")
        how = "numerically null" if self.stderr is None else f"± {self.stderr:.2g} of the ranges"
        return f"{terms} ({how})"


@dataclass(frozen=True)
class Ablation:
    """What one refined term removes: the written model's MAE at h = H with that term back at its one-step
    values, on the training and the held-out windows (p, v, R, ω)."""

    term: str
    training: tuple  # MAE at H without the term, per quantity
    held_out: tuple | None


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
    # model (extended, refined, rate_frozen) -> its qr.rollout.summary block on the training windows
    training: Mapping[str, RolloutBlock]
    held_out: Mapping[str, RolloutBlock]  # the same on the held-out windows (none: empty)
    wall_s: float
    not_candidates: Mapping[str, str] = field(default_factory=dict)  # coefficient → why it was not refined
    unconstrained: tuple = ()  # Direction: parameter combinations the data cannot fix (held at one-step values)
    ablation: tuple = ()  # Ablation rows: what each refined term removes of the rollout error at H
    diverged: int = 0  # training windows whose rollout (of the written model) diverged, scored as the protocol does
    # extra term → (held-out loss without, with, admitted); "beyond: hold or bound" → (held, within range, bound)
    admission: Mapping[str, tuple[float | None, float | None, bool]] = field(default_factory=dict)
    balance_ref: np.ndarray | None = None  # the one-step model's force and torque balance rms per axis
    balance: np.ndarray | None = None  # the written model's balance residual per axis over the one-step model's
    # the sandwich covariance (parameter units) of the parameters off their bounds at the rollout's optimum:
    # (their indices into ``parameters``, the matrix), over the directions the data fix (_band_covariance); the Monte
    # Carlo band's draws (qr.bands)
    covariance: tuple | None = None
    band_scale: Scale | None = None  # the band's scale per quantity, chosen on the training flights (calibration_windows)
    band_scale50: Scale | None = None  # the 50 % band's

    def properties(self) -> dict:
        """The vehicle keys refined (only those that moved): ``rotor_inertia``, ``rotor_torque_gains``,
        ``flapping_pitch_ratio``."""
        out: dict = {}
        for key in PROPERTIES:
            ps = [p for p in self.parameters if p.effect == key]
            if ps and any(p.written != p.one_step for p in ps):
                out[key] = [p.written for p in ps] if key == "rotor_torque_gains" else ps[0].written
        return out

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
        for eff in COEFFICIENTS:  # (PROPERTIES are vehicle keys: properties())
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
            "parameters": [p.to_json() for p in self.parameters],
            "not_candidates": self.not_candidates,
            "vehicle_keys": self.properties(),
            "unconstrained": [d.to_json() for d in self.unconstrained],
            "ablation": {"quantities": list(QUANTITIES), "horizon": H,
                         "rows": [{"term": a.term, "training_mae_at_H": list(a.training) if a.training else None,
                                   "held_out_mae_at_H": list(a.held_out) if a.held_out else None}
                                  for a in self.ablation]},
            "diverged_windows": self.diverged,
            "balance": None if self.balance is None else {
                "tolerance": BALANCE_TOL, "axes": ["fx", "fy", "fz", "tx", "ty", "tz"],
                "one_step_rms": [float(x) for x in self.balance_ref],
                "written_over_one_step": [float(x) for x in self.balance]},
            "admission": {g: {"held_out_loss_without": a, "held_out_loss_with": b, "admitted": ok}
                          for g, (a, b, ok) in self.admission.items() if not g.startswith("beyond")},
            "beyond_range": ({"held_out_loss_held": self.admission["beyond: hold or bound"][0],
                              "held_out_loss_within_range": self.admission["beyond: hold or bound"][1],
                              "written": "within range" if self.admission["beyond: hold or bound"][2] else "held"}
                             if "beyond: hold or bound" in self.admission else None),
            "training": {"loss_before": self.loss_before, "loss_after": self.loss_after,
                         "loss_wanted": self.loss_wanted, "ratio_to_rate_frozen_at_H": ratios(self.training),
                         "mae_at_H": mae(self.training)},
            "held_out": {"ratio_to_rate_frozen_at_H": ratios(self.held_out), "mae_at_H": mae(self.held_out),
                         "windows": int(self.held_out["rate_frozen"]["p"]["windows"]) if self.held_out else 0},
            "statements": statements(self),
            **({"parameter_covariance": {
                "parameters": [int(i) for i in self.covariance[0]],
                "labels": [self.parameters[int(i)].label for i in self.covariance[0]],
                "matrix": [[float(x) for x in row] for row in self.covariance[1]],
                "units": "each parameter's own (as parameters[].written)",
                "at": "the rollout's optimum within the plausible bounds (rollout), parameters off their bounds",
                "band_scale": self.band_scale, "band_scale50": self.band_scale50,
                "calibrated_on": f"the training flights' windows, one start in {self.stride}, their training and "
                                 "held-out parts alike (qr.bands: each band covers its share there)"}}
               if self.covariance is not None and len(self.covariance[0]) else {}),
        }


# ---- the compiled rollout: residuals, and the normal equations of their Jacobian -------------------

@nb.njit(cache=True)
def _window(t, X0, U, i, H, P, tp, tq, tv, tw, out, k, xs, xn, x, states):
    """The error vectors (H, 12) of the window starting at ``i`` (zero rows where the truth is missing), by
    the evaluate protocol's own rollout (:func:`qr.rollout.roll_window`: a diverged rollout's last sane state
    stands for the rest of the window, as ``qr evaluate`` scores it); True if it diverged."""
    r = P[P_MARKER].copy()
    _, diverged = roll_window(t, X0, U, i, H, P, MODEL, r, states, k, xs, xn, x)
    p, v, q, w = X_POS.start, X_VEL.start, X_QUAT.start, X_RATE.start
    for h in range(1, H + 1):
        j = i + h
        y = states[h - 1]
        row = out[h - 1]
        for m in range(12):
            row[m] = 0.0
        if math.isfinite(tp[j, 0]):
            row[0], row[1], row[2] = y[p] - tp[j, 0], y[p + 1] - tp[j, 1], y[p + 2] - tp[j, 2]
        if math.isfinite(tv[j, 0]):
            row[3], row[4], row[5] = y[v] - tv[j, 0], y[v + 1] - tv[j, 1], y[v + 2] - tv[j, 2]
        if math.isfinite(tq[j, 0]):
            e0, a, b, c = qmul_s(tq[j, 0], -tq[j, 1], -tq[j, 2], -tq[j, 3], y[q], y[q + 1], y[q + 2], y[q + 3])
            s = 2.0 if e0 >= 0 else -2.0
            row[6], row[7], row[8] = s * a, s * b, s * c
        if math.isfinite(tw[j, 0]):
            row[9], row[10], row[11] = y[w] - tw[j, 0], y[w + 1] - tw[j, 1], y[w + 2] - tw[j, 2]
    return diverged


@nb.njit(cache=True, nogil=True)
def _normal(t, X0, Us, starts, lo, hi, tp, tq, tv, tw, H, Ps, uix, nix, dtheta, weight, A, Ad, g, gw, out):
    """Windows ``lo … hi−1``: ``out`` = [cost, windows whose rollout diverged (scored as the protocol scores
    them)]; with variants (``Ps[1 + k]``:
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
    k4, xs, xn, x = np.empty((4, N_RB)), np.empty(N_RB), np.empty(N_RB), np.empty(N_RB)
    states = np.empty((H, N_RB))
    for w_i in range(lo, hi):
        i = starts[w_i]
        # every window counts in every pass (the cost's and each variant's): a diverged rollout is scored
        # as the protocol scores it, so a step that makes windows diverge is no cheaper
        if _window(t, X0, Us[uix[0]], i, H, Ps[0], tp, tq, tv, tw, E[0], k4, xs, xn, x, states):
            out[1] += 1.0
        for v in range(K):
            if v > 0:
                _window(t, X0, Us[uix[v]], i, H, Ps[v], tp, tq, tv, tw, E[v], k4, xs, xn, x, states)
            if corr:
                _window(t, X0, Us[nix[v]], i, H, Ps[v], tp, tq, tv, tw, D[v], k4, xs, xn, x, states)
                for h in range(H):
                    for m in range(12):
                        D[v, h, m] -= E[v, h, m]
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


@nb.njit(cache=True)
def _balance_sums(X, Ut, Uf, al, acc, P, out):
    """``out`` (6,) += Σ over rows of the squared force (world, N) and torque (body, N m) balance residuals of
    the plant ``P``: ``m (a − â)`` of the tracked point (the marker terms from the measured α, ω) and
    ``J (α − α̂)``, ``Uf`` / ``Ut`` the force- and torque-matched rotor speeds; rows with a NaN are skipped."""
    r = P[P_MARKER].copy()
    zero = np.zeros(3)
    x = np.empty(N_RB)
    n = 0
    for i in range(X.shape[0]):
        ok = True
        for m in range(N_RB):
            if not math.isfinite(X[i, m]):
                ok = False
        for m in range(3):
            if not (math.isfinite(al[i, m]) and math.isfinite(acc[i, m])):
                ok = False
        if not ok:
            continue
        x[:] = X[i]
        cg_from_tracked(x, r)
        a, _ = plant_accels(x, Uf[i], P, zero, zero)
        _, alpha = plant_accels(x, Ut[i], P, zero, zero)
        _, _, at = tracked_point(x, a, al[i], r)
        for m in range(3):
            df = P[P_MASS] * (acc[i, m] - at[m])
            dt = P[P_J.start + m] * (al[i, m] - alpha[m])
            out[m] += df * df
            out[3 + m] += dt * dt
        n += 1
    return n


@dataclass
class Balance:
    """The training rows' force and torque balance (the equation error the one-step fit minimises): the
    written model may roll out better only while no axis's residual grows by more than ``BALANCE_TOL`` of the
    one-step model's (:meth:`_Fit.minimise` with it: a penalty beyond that)."""

    t: np.ndarray  # (N,) s
    X: np.ndarray  # (N, 13) the estimated tracked-point state
    Ut: np.ndarray  # (N, 4) rotor speeds matched to the attitude estimate (torque rows)
    Uf: np.ndarray  # (N, 4) rotor speeds matched to the position estimate (force rows)
    alpha: np.ndarray  # (N, 3) estimated angular acceleration (body)
    acc: np.ndarray  # (N, 3) estimated acceleration of the tracked point (world)
    offsets: list  # per piece: (row offset, n)

    def rms(self, P: np.ndarray) -> np.ndarray:
        """Per axis (fx, fy, fz, τx, τy, τz) the RMS balance residual of the plant ``P`` (its delay applied)."""
        from ..rollout import _delayed

        d = float(P[P_DELAY])
        Ut, Uf = self.Ut, self.Uf
        if d > 0:
            Ut, Uf = np.empty_like(Ut), np.empty_like(Uf)
            for o, n in self.offsets:
                Ut[o:o + n] = _delayed(self.t[o:o + n], self.Ut[o:o + n], d)
                Uf[o:o + n] = _delayed(self.t[o:o + n], self.Uf[o:o + n], d)
        out = np.zeros(6)
        n = _balance_sums(self.X, np.ascontiguousarray(Ut), np.ascontiguousarray(Uf), self.alpha, self.acc, P, out)
        return np.sqrt(out / max(n, 1))


def balance_rows(states_list, owner: list[int], windows: list[dict], trim_s: float) -> Balance | None:
    """The training part's rows (trimmed) of each state table, as :class:`Balance` reads them (None where the
    estimates lack the angular or linear acceleration)."""
    from ..states import POSITION, QUATERNION, RATE, ROTORS, U2_FORCE, U2_TORQUE, VELOCITY

    parts, o, offsets = [], 0, []
    for st, f in zip(states_list, owner):
        if not {"alx", "aly", "alz", "ax", "ay", "az"} <= set(st.columns):
            return None
        t = st["t"].to_numpy(float)
        keep = (t >= max(windows[f]["train"][0], t[0] + trim_s)) & (t <= min(windows[f]["train"][1], t[-1] - trim_s))
        if not keep.any():
            continue
        s = st[keep]
        u = s[ROTORS].to_numpy(float)
        ut = np.sqrt(np.maximum(s[U2_TORQUE].to_numpy(float), 0.0)) if set(U2_TORQUE) <= set(s.columns) else u
        uf = np.sqrt(np.maximum(s[U2_FORCE].to_numpy(float), 0.0)) if set(U2_FORCE) <= set(s.columns) else u
        parts.append((s["t"].to_numpy(float), s[POSITION + VELOCITY + QUATERNION + RATE].to_numpy(float), ut, uf,
                      s[["alx", "aly", "alz"]].to_numpy(float), s[["ax", "ay", "az"]].to_numpy(float)))
        offsets.append((o, int(keep.sum())))
        o += int(keep.sum())
    if not parts:
        return None
    cat = [np.ascontiguousarray(np.concatenate([p[k] for p in parts])) for k in range(6)]
    return Balance(*cat, offsets)


# ---- the parameters --------------------------------------------------------------------------------

@dataclass
class _Spec:
    effect: str  # a catalog effect, or a vehicle key (PROPERTIES)
    name: str  # the effect's parameter, or the key's index ("" for a scalar key)
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

    @property
    def vehicle_key(self) -> bool:
        return self.effect in PROPERTIES


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


def property_range(key: str, vehicle) -> tuple[float, float]:
    """A vehicle property's physical range (the plausible bounds are the same): each rotor's C_Q within
    ``ROTOR_GAIN_RANGE`` of the file's; the rotor inertia up to a rotor of ``ROTOR_MASS_SHARE`` of the mass
    all at the largest rotor distance r (no propeller reaches beyond its neighbours' hubs); the flapping
    ratio within ``FLAP_RATIO_RANGE``."""
    if key == "rotor_torque_gains":
        return ROTOR_GAIN_RANGE
    if key == "rotor_inertia":
        r = float(np.max(np.hypot(*vehicle.rotors.positions.T)))
        return 0.0, ROTOR_MASS_SHARE * vehicle.mass * r * r
    return FLAP_RATIO_RANGE


def _property_specs(vehicle, named: list[str], settings: RefineSettings, why: dict) -> list[_Spec]:
    """The rotor and airframe properties refined (``diagnose.refine_rotors``): each rotor's yaw-torque gain,
    the rotors' inertia, and with blade flapping named its pitch/roll ratio."""
    if not settings.rotors:
        why["rotor properties"] = "not candidates (diagnose.refine_rotors=false)"
        return []
    out = []
    for key in PROPERTIES:
        if key == "flapping_pitch_ratio" and "blade_flapping" not in named:
            why[key] = "not a candidate: blade flapping is not named"
            continue
        lo, hi = property_range(key, vehicle)
        if key == "rotor_torque_gains":
            for i, g in enumerate(vehicle.rotor_torque_gains):
                out.append(_Spec(key, str(i), False, float(g), None, lo, hi, lo, hi, 0.1, 1.0))
        elif key == "rotor_inertia":
            out.append(_Spec(key, "", False, vehicle.rotor_inertia, None, lo, hi, lo, hi, max(hi * 1e-2, 1e-12), 0.0))
        else:
            out.append(_Spec(key, "", False, vehicle.flapping_pitch_ratio, None, lo, hi, lo, hi, 0.1, 1.0))
    return out


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
        elif eff in ("motor_imbalance", "cg_offset") and not settings.rotors:
            why[eff] = "not a candidate (diagnose.refine_rotors=false)"
        elif eff == "motor_imbalance" and "mass_error" in named:
            why[eff] = "confounded with the named mass_error (its common part is a C_T error)"
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
            elif e["name"] == "motor_imbalance":
                scale = 0.01
            elif e["name"] == "cg_offset":
                scale = 0.01 * float(np.max(np.hypot(*vehicle.rotors.positions.T)))
            else:
                width = float(hi[k] - lo[k]) if np.isfinite(hi[k] - lo[k]) else 0.0
                scale = max(abs(x), se or 0.0, 1e-3 * width, 1e-12)
            out.append(_Spec(e["name"], p, e in effects, min(max(x, float(lo[k])), float(hi[k])), se, float(lo[k]),
                             float(hi[k]), plo, phi, scale, ref,
                             tuple(f for f, lead in follows.items() if lead == e["name"])))
    return out + _property_specs(vehicle, named, settings, why), why


def _effects_of(specs: list[_Spec], theta: np.ndarray) -> list[dict]:
    """The catalog effects of ``theta`` (the vehicle properties are :func:`_properties_of`)."""
    d: dict = {}
    for s, x in zip(specs, theta):
        if not s.vehicle_key:
            for e in (s.effect, *s.followers):
                d.setdefault(e, dict(zip(CATALOG[e].params, CATALOG[e].neutral)))[s.name] = float(x)
    return [{"name": e, "parameters": k} for e, k in d.items()]


def _properties_of(specs: list[_Spec], theta: np.ndarray) -> dict:
    """The vehicle keys of ``theta`` (``rotor_torque_gains`` as a list)."""
    out: dict = {}
    for s, x in zip(specs, theta):
        if s.effect == "rotor_torque_gains":
            out.setdefault(s.effect, []).append(float(x))
        elif s.vehicle_key:
            out[s.effect] = float(x)
    return out


def _plant(vehicle, specs: list[_Spec], theta: np.ndarray) -> np.ndarray:
    """The plant vector of ``theta``: the vehicle with its refined properties, its effects and ``theta``'s."""
    props = _properties_of(specs, theta)
    v = vehicle.with_changes(**props) if props else vehicle
    return true_params(v, vehicle.effects + _effects_of(specs, theta), residual=False)


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
           log=lambda msg: None, balance: "Balance | None" = None) -> Refinement:
    """Refine ``effects`` (the named effects: ``{name, parameters, stderr}``, the equation-error
    estimates) and the vehicle's coefficients on the ``train`` windows by the rollout's error; score the
    equation-error and the refined model on ``held_out``.  ``rotor_noise``: per training piece, the rotor
    speeds' noise (measured less filtered; None: no errors-in-variables correction); ``seed``: its
    realisation.  Two fits: what the rollout wants within the plausible bounds, then the written model within
    the physical ranges (docs/diagnose.md "Refinement by simulation error", "What is written")."""
    t0 = time.perf_counter()
    H = settings.horizon
    specs, why = _specs(vehicle, effects, settings)
    stack = _stack(train, H, settings.stride, max(settings.block_s, 4 * H * _median_dt(train)), rotor_noise, seed)
    weight = _weights(train, vehicle, H) * np.asarray(settings.signal_weights, float)
    fit = _Fit(stack, vehicle, specs, H, weight)
    theta0 = np.array([s.start for s in specs])
    log(f"refining {len(specs)} parameters on {len(stack.starts)} training windows of {H} steps")
    free, wanted, iters, stopped, admission = _admit(fit, specs, theta0, held_out, vehicle, H, weight, settings, log)
    cov_wanted = fit.covariance(wanted, free)
    se = fit.stderr(wanted, cov_wanted)
    params = _parameters(specs, wanted, se, free)
    beyond = np.array([not p.in_range or (p.bound_hit is not None and p.rollout != p.one_step) for p in params])
    beyond &= free
    # the written model keeps the force and torque balance (every axis within 1 + BALANCE_TOL of the one-step
    # model's): the fit starts from the one-step model and shortens any step that would break it
    limits = _balance_check(balance, vehicle, specs, theta0) if balance is not None else None
    # the directions the data cannot fix around the one-step model (where the written fit starts): reported, and
    # held at their one-step values in the written fit
    directions, pin = _unconstrained(fit, specs, fit.covariance(theta0, free))
    rules = ("hold", "bound") if settings.beyond == "auto" and beyond.any() else \
        ("hold" if settings.beyond == "auto" else settings.beyond,)
    candidates = {}
    for rule in rules:
        candidates[rule] = _written(fit, specs, params, theta0, wanted, free, beyond, pin, rule, settings, log, limits)
        iters += candidates[rule][1]
    written, _, stopped2 = candidates[_beyond_rule(fit, held_out, settings, candidates, admission)]
    if stopped2:
        stopped = f"{stopped}; the written model: {stopped2}"
    balance_after = None
    if balance is not None:  # jointly too: back towards the one-step model until every axis keeps its balance
        written, balance_after = _within_balance(balance, vehicle, specs, theta0, written)
    if fit.cost(written) >= fit.cost(theta0):  # no better than the one-step model on the training windows
        written = theta0
        stopped += "; the written model is the one-step one (what the refinement may write does not lower the loss)"
    from dataclasses import replace

    params = [replace(p, written=float(x)) for p, x in zip(params, written)]
    blocks_train = _blocks(train, vehicle, effects, specs, written, H)
    blocks_test = _blocks(held_out, vehicle, effects, specs, written, H) if held_out else {}
    ablation = _ablation(train, held_out, stack, vehicle, specs, theta0, written, H)
    diverged = fit.normal(written, [])[5]
    covariance = _band_covariance(fit, specs, cov_wanted)
    band_scale, band_scale50 = _band_scale(calibration_windows(train, held_out, settings.stride), vehicle, specs,
                                           written, covariance, H, seed)
    return Refinement(tuple(params), len(stack.starts), stack.lag, H, settings.stride, iters, stopped,
                      fit.cost(theta0), fit.cost(written), fit.cost(wanted), blocks_train, blocks_test,
                      time.perf_counter() - t0, why, tuple(directions), ablation, diverged, admission,
                      None if limits is None else limits[1], balance_after, covariance, band_scale,
                      band_scale50)


def _parameters(specs: list[_Spec], wanted, se, free) -> list[Parameter]:
    """Each parameter's record after the first fit (what the rollout wants; its written value set later): a
    value on a plausible bound has no standard error."""
    params = []
    for k, s in enumerate(specs):
        hit = "lower" if wanted[k] <= s.lo + 1e-9 * s.scale else ("upper" if wanted[k] >= s.hi - 1e-9 * s.scale
                                                                   else None)
        params.append(Parameter(s.effect, s.name, _label(s), s.named, s.start, s.start_se, float(wanted[k]),
                                None if hit or not np.isfinite(se[k]) else float(se[k]), float(wanted[k]),
                                (s.lo, s.hi), (s.phys_lo, s.phys_hi), hit if free[k] else None, s.reference,
                                bool(free[k]), s.followers))
    return params


def _beyond_rule(fit, held_out: list[Windows], settings: RefineSettings, candidates: dict, admission: dict) -> str:
    """Which written model stands when parameters were wanted beyond their ranges: the first rule alone, or of
    "hold" and "bound" the one with the lower loss on the held-out windows (the diagnosis's held-out part of the
    same flights; "hold" on a tie), recorded in ``admission``."""
    rules = list(candidates)
    if len(rules) == 1:
        return rules[0]
    val = _validation(fit, held_out, settings) if held_out else None
    losses = {r: val.cost(c[0]) for r, c in candidates.items()} if val is not None else {}
    rule = min(losses, key=lambda r: (losses[r], r != "hold")) if losses else "hold"
    admission["beyond: hold or bound"] = (losses.get("hold"), losses.get("bound"), rule == "bound")
    return rule


def calibration_windows(train: list[Windows], held_out: list[Windows], stride: int) -> list[Windows]:
    """The windows the band's scale is chosen on: every ``stride``-th start of the training flights, their
    training and held-out parts alike.  A scored flight is scored over all its phases (the manoeuvre, the hover
    before landing); the held-out part alone is each flight's last quarter, on measured flights its gentlest,
    and chose scales too small for whole flights (docs/evaluate.md, Bands).  With ~20 parameters fitted on
    thousands of windows the training windows' errors are hardly smaller than a new flight's for it."""
    return [w.scored_at(np.flatnonzero(w.ok)[::stride]) for w in (*train, *held_out) if w.ok.any()]


def _band_scale(windows: list[Windows], vehicle, specs: list[_Spec], written, covariance, H: int,
                seed: int) -> tuple[dict | None, dict | None]:
    """The Monte Carlo band's scales per quantity of its 90 % and 50 % levels (:func:`qr.bands.calibrate_levels`)
    on ``windows`` (:func:`calibration_windows`): the written model and ``BAND_DRAWS`` draws of its parameters
    from the covariance, each within its bounds."""
    idx, cov = covariance
    if not windows or not len(idx):
        return None, None
    from .. import bands

    bounds = np.array([[specs[i].lo, specs[i].hi] for i in idx])
    thetas = bands.draw_parameters(written[idx], cov, bounds, BAND_DRAWS, seed)
    Ps = [_plant(vehicle, specs, written)]
    for th in thetas:
        full = written.copy()
        full[idx] = th
        Ps.append(_plant(vehicle, specs, full))
    return bands.calibrate_levels(bands.spread(windows, np.array(Ps), H))


BAND_DRAWS = BandsConfig().draws  # evaluate.bands.draws' default: the band calibrated is the band evaluated


def _balance_check(balance: "Balance", vehicle, specs: list[_Spec], theta0) -> tuple:
    """``(ratios, ref)``: a parameter vector's force and torque balance residual per axis over the one-step
    model's (``ref``, per axis); the written model keeps every ratio within ``1 + BALANCE_TOL``."""
    ref = balance.rms(_plant(vehicle, specs, theta0))
    ref = np.where(ref > 0, ref, 1.0)
    return (lambda th: balance.rms(_plant(vehicle, specs, th)) / ref), ref


def _within_balance(balance: "Balance", vehicle, specs, theta0, theta) -> tuple:
    """``(theta, rms ratio per axis)``: the written model, moved back along the line to the one-step model
    (bisection, 12 halvings) until no axis's balance residual exceeds ``1 + BALANCE_TOL`` times the one-step
    model's."""
    ref = balance.rms(_plant(vehicle, specs, theta0))
    ref = np.where(ref > 0, ref, 1.0)
    ratio = lambda th: balance.rms(_plant(vehicle, specs, th)) / ref  # noqa: E731
    q = ratio(theta)
    if q.max() <= 1.0 + BALANCE_TOL:
        return theta, q
    a, b = 0.0, 1.0
    for _ in range(12):
        m = 0.5 * (a + b)
        if ratio(theta0 + m * (theta - theta0)).max() <= 1.0 + BALANCE_TOL:
            a = m
        else:
            b = m
    out = theta0 + a * (theta - theta0)
    return out, ratio(out)


def _written(fit: "_Fit", specs, params, theta0, wanted, free, beyond, pin, rule: str, settings, log,
             limits=None) -> tuple:
    """``(theta, iterations, stopped)``: the model written, a second fit within the physical ranges, from the
    one-step model and keeping the force and torque balance where ``limits`` (:func:`_balance_check`) is
    given, else from what the rollout wants.  A parameter not admitted stays at its one-step value; so does a
    named effect's the rollout wants beyond its standard errors from the one-step estimate, and one wanted
    beyond its physical range with ``rule`` "hold" (with "bound": it is fitted again within its range, so it
    may end at the range's end); the directions the data cannot fix stay at their one-step values (``pin``)."""
    disagree = np.array([p.named and p.disagree for p in params])
    held = disagree | ~free | (beyond if rule == "hold" else False)
    lo = np.array([s.phys_lo for s in specs])
    hi = np.array([s.phys_hi for s in specs])
    if limits is None and not ((held & free).any() or beyond.any() or pin is not None):
        return wanted, 0, ""
    if (held & free).any():
        log(f"held at the one-step value in the written model ({rule}): "
            + ", ".join(p.label for p, h, f in zip(params, held, free) if h and f))
    # a held one stays at its one-step value, even where the diagnosis named it outside the range (said in the
    # report; the refinement does not move it)
    phys = (np.where(held, np.minimum(theta0, lo), lo), np.where(held, np.maximum(theta0, hi), hi))
    if limits is not None:
        start = theta0.copy()
    else:
        start = np.clip(np.where(held, theta0, wanted), *phys)
        if pin is not None:  # start on the pinned directions' one-step values
            start = np.clip(_project_out(start, theta0, pin, fit.scale), *phys)
    return fit.minimise(start, ~held, settings.iterations, bounds=phys, pin=None if pin is None else (pin, theta0),
                        constraint=None if limits is None else (limits[0], 1.0 + BALANCE_TOL))


# The terms a rollout most easily bends into compensation for what the model lacks (per-rotor gains, the CG,
# the rotors' inertia, the flapping ratio): each is admitted only where, fitted beside the others, it lowers
# the rollout loss on the held-out windows (the diagnosis's held-out part of the same flights) by ADMIT_GAIN.
EXTRA_TERMS = ("motor_imbalance", "cg_offset", *PROPERTIES)
ADMIT_GAIN = 0.02
# The written model keeps the force and torque balance it is measured by: no axis's equation-error residual
# on the training rows may grow by more than BALANCE_TOL of the one-step model's (the rollout bends what it
# can into a low-pass on torques the model lacks: J x 7, per-rotor gains traded against the CG; the
# balance, measured sample by sample, tells such values from physical ones)
BALANCE_TOL = 0.05


def _admit(fit: "_Fit", specs: list[_Spec], theta0, held_out: list[Windows], vehicle, H: int, weight, settings,
           log) -> tuple:
    """``(free, wanted, iterations, stopped, admission)``: the first fit (every admitted parameter free
    within its plausible bounds).  The named effects and the vehicle's J, C_T, C_Q and delay are always
    free; each of ``EXTRA_TERMS`` is fitted beside them (from their optimum) and admitted where it lowers
    the held-out windows' loss by ``ADMIT_GAIN`` of it (without held-out windows none is).  ``admission``:
    per term tried, ``(held-out loss without, with, admitted)``."""
    group = np.array([s.effect if (s.effect in EXTRA_TERMS and not s.named) else "" for s in specs])
    base = group == ""
    theta, iters, stopped = fit.minimise(theta0, base, settings.iterations)
    terms = [g for g in EXTRA_TERMS if (group == g).any()]
    admission: dict = {}
    if not terms:
        return base, theta, iters, stopped, admission
    val = _validation(fit, held_out, settings) if held_out else None
    if val is None:
        for g in terms:
            admission[g] = (None, None, False)
        return base, theta, iters, stopped, admission
    before = val.cost(theta)
    free = base.copy()
    # one Jacobian of every parameter at the base optimum; each term's trial is the Levenberg–Marquardt step
    # from there with it freed (a step the training loss accepts), judged on the held-out windows
    every = np.flatnonzero(base | (group != ""))
    normal = fit.normal(theta, every)
    for g in terms:
        trial = fit.step(theta, base | (group == g), every, normal)
        after = val.cost(trial)
        ok = bool(after < (1.0 - ADMIT_GAIN) * before)
        admission[g] = (before, after, ok)
        log(f"{g}: held-out loss {before:.4g} -> {after:.4g} ({'admitted' if ok else 'not admitted'})")
        if ok:
            free |= group == g
    if free.sum() > base.sum():
        theta, more, stopped = fit.minimise(theta, free, settings.iterations)
        iters += more
    return free, theta, iters, stopped, admission


def _validation(fit: "_Fit", held_out: list[Windows], settings) -> "_Fit | None":
    """The loss on the held-out windows (every stride-th start, the training weights; no noise correction)."""
    try:
        stack = _stack(held_out, fit.H, settings.stride, 1.0, None, 0)
    except QrInputError:
        return None
    val = _Fit(stack, fit.vehicle, fit.specs, fit.H, fit.weight * len(fit.stack.starts))
    return val


# A direction is unconstrained when ±2 standard errors along it span more than half of the parameters'
# physical ranges (the data do not narrow it to less than what physics allows), or its curvature is
# numerically zero (UNFIXED_CURVATURE of the largest: an exact confound, e.g. C_T against four equal
# per-rotor gains).
UNFIXED_SE = 0.25
UNFIXED_CURVATURE = 1e-10
PIN_WEIGHT = 1e4  # the penalty holding an unconstrained direction, in units of the largest curvature


def _ranges(specs: list[_Spec]) -> np.ndarray:
    """Each parameter's physical range width (its plausible one where unbounded; 1000 scales at most)."""
    out = []
    for s in specs:
        w = s.phys_hi - s.phys_lo
        if not np.isfinite(w) or w <= 0:
            w = s.hi - s.lo
        out.append(w if np.isfinite(w) and w > 0 else 1e3 * s.scale)
    return np.array(out)


def _unconstrained(fit: "_Fit", specs: list[_Spec], cov) -> tuple[list[Direction], np.ndarray | None]:
    """The parameter directions the data cannot fix at the rollout's optimum and the penalty matrix (scaled
    parameters, all of them) that holds them at their one-step values in the written fit (None: none).

    In units of each parameter's physical range, the Gauss–Newton Hessian's eigen-directions v with their
    sandwich standard error ``√(vᵀ B v) / λ``: unconstrained where that exceeds ``UNFIXED_SE`` or λ is
    numerically zero.  The eigen-decomposition is compiled (fixed order: the same on any BLAS)."""
    idx = cov[0]
    if idx.size < 1:
        return [], None
    R, w, V, se, top = _range_eigen(fit, specs, cov)
    labels = [_label(specs[i]) for i in idx]
    out, cols = [], []
    for k in range(idx.size):
        v = V[:, k]
        if se[k] <= UNFIXED_SE:
            continue
        v = v * (1.0 if v[np.argmax(np.abs(v))] > 0 else -1.0)
        order = np.argsort(-np.abs(v), kind="stable")
        out.append(Direction(tuple((labels[j], float(v[j])) for j in order if abs(v[j]) >= 0.1),
                             float(max(w[k], 0.0) / top), None if np.isinf(se[k]) else float(se[k])))
        full = np.zeros(len(specs))
        full[idx] = v / R  # in the scaled parameters
        cols.append(full)
    if not cols:
        return out, None
    Vu = np.array(cols).T
    return out, PIN_WEIGHT * top * (Vu @ Vu.T)


def _range_eigen(fit: "_Fit", specs: list[_Spec], cov) -> tuple:
    """``(R, w, V, se, top)`` of :meth:`_Fit.covariance`'s ``(idx, H, B)``: in units of each parameter's
    physical range (scaled parameter z = R z_r), the Hessian's eigenvalues ``w`` and vectors ``V`` (compiled,
    fixed order: the same on any BLAS), each direction's sandwich standard error ``√(vᵀ B v) / λ`` (∞ where
    λ is numerically zero, ``UNFIXED_CURVATURE`` of the largest) and the largest eigenvalue."""
    from ..linalg_compiled import symmetric_eigen

    idx, Hm, B = cov
    R = _ranges(specs)[idx] / fit.scale[idx]
    Hr = Hm * R[:, None] * R[None, :]
    Br = B * R[:, None] * R[None, :]
    w, V = np.empty(idx.size), np.empty((idx.size, idx.size))
    symmetric_eigen(np.ascontiguousarray(Hr), w, V)
    top = max(float(w.max()), 1e-300)
    se = np.array([math.inf if w[k] <= UNFIXED_CURVATURE * top
                   else math.sqrt(max(float(V[:, k] @ Br @ V[:, k]), 0.0)) / w[k] for k in range(idx.size)])
    return R, w, V, se, top


def _band_covariance(fit: "_Fit", specs: list[_Spec], cov) -> tuple:
    """``(idx, Σ)``: the sandwich covariance the band draws from (:meth:`_Fit.sandwich`) over the directions
    the data fix (those :func:`_unconstrained` reports are left out: the written model holds them at their
    one-step values; along an exact confound such as C_T against four equal per-rotor gains the variance is
    the inverse's round-off, and draws along a direction wider than the physical ranges, clipped to each
    parameter's bounds one by one, fly vehicles the data exclude, the band's 90 % radius then set by a few
    diverging draws).  Without such a direction: :meth:`_Fit.sandwich` itself."""
    from ..linalg_compiled import congruence, eigen_inverse

    idx, Hm, B = cov
    if idx.size < 1:
        return fit.sandwich(cov)
    R, w, V, se, _ = _range_eigen(fit, specs, cov)
    keep = se <= UNFIXED_SE
    if keep.all():
        return fit.sandwich(cov)
    # A⁺ B A⁺ over the directions kept (range units), then back to parameter units: θ = scale · R · z_r
    Br = np.ascontiguousarray(B * R[:, None] * R[None, :])
    inv, S = np.empty_like(Br), np.empty_like(Br)
    eigen_inverse(V, np.where(keep, w, 0.0), inv)
    congruence(inv, Br, S)
    u = fit.scale[idx] * R
    return idx, 0.5 * (S + S.T) * np.outer(u, u)


def _project_out(theta: np.ndarray, theta0: np.ndarray, pin: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """``theta`` with its components along the pinned directions moved back to ``theta0``'s."""
    from ..linalg_compiled import symmetric_eigen

    n = len(theta)
    w, V = np.empty(n), np.empty((n, n))
    symmetric_eigen(np.ascontiguousarray(pin), w, V)
    U = V[:, w > 1e-9 * max(float(w.max()), 1e-300)]
    U = U / np.sqrt((U * U).sum(axis=0))
    d = (theta - theta0) / scale
    return theta0 + (d - U @ (U.T @ d)) * scale


def _ablation(train, held_out, stack, vehicle, specs: list[_Spec], theta0, written, H) -> tuple:
    """Per refined term (a catalog effect or a vehicle property whose values moved): the written model's
    MAE at H with that term back at its one-step values, on the refinement's training windows and the
    held-out ones; first the written model itself (``refined``) and the one-step one (``one-step``)."""
    from ..rollout import pool

    starts = [stack.starts[stack.piece == k] - stack.offsets[k][0] for k in range(len(train))]
    wins = [w.scored_at(s) for w, s in zip(train, starts) if len(s)]

    def mae(theta, pieces):
        if not pieces:
            return None
        P = _plant(vehicle, specs, theta)
        s, c = pool([{"m": score_plant(w, H, P, MODEL)} for w in pieces])["m"]
        return tuple(float(x) for x in s[H - 1] / np.maximum(c[H - 1], 1))

    rows = [Ablation("refined", mae(written, wins), mae(written, held_out)),
            Ablation("one-step", mae(theta0, wins), mae(theta0, held_out))]
    groups: dict = {}
    for k, s in enumerate(specs):
        groups.setdefault(s.effect, []).append(k)
    for term, ks in groups.items():
        if not any(written[k] != theta0[k] for k in ks):
            continue
        th = written.copy()
        th[ks] = theta0[ks]
        rows.append(Ablation(term, mae(th, wins), mae(th, held_out)))
    return tuple(rows)


def _label(s: _Spec) -> str:
    own = LABELS.get((s.effect, s.name)) or f"{s.effect}.{s.name}"
    return own + "".join(f" = {f}.{s.name}" for f in s.followers)


def _median_dt(pieces: list[Windows]) -> float:
    return float(np.median(np.concatenate([np.diff(w.t) for w in pieces])))


def _weights(train: list[Windows], vehicle, H: int) -> np.ndarray:
    """1 / ref_s² per signal: rate_frozen's mean error over h on the training windows
    (:func:`qr.rollout.reference_mae`; 1 where a signal has no truth)."""
    from ..rollout import reference_mae

    ref = reference_mae(train, vehicle, H)
    ref = np.where(np.isfinite(ref) & (ref > 0), ref, 1.0)
    return 1.0 / ref**2


def _kept(constraint, theta, trial, z, dz, idx, sc, bounds, grad):
    """A trial step of :meth:`_Fit.minimise` that keeps ``constraint`` (``(c, limit)``): one that breaks it is
    projected onto the tangent plane of the components it breaks (their finite-difference gradients at
    ``theta``, computed once per iteration: ``grad``, None until then), then halved up to 10 times; no step
    if none keeps it.  The trial and ``grad``."""
    c_fn, limit = constraint
    blo, bhi = bounds
    ct = c_fn(trial)
    if (ct > limit).any():
        if grad is None:
            c0 = c_fn(theta)
            grad = np.empty((len(c0), idx.size))
            for j, k in enumerate(idx):
                th = theta.copy()
                h = FD_STEP * sc[j] if theta[k] + FD_STEP * sc[j] <= bhi[k] else -FD_STEP * sc[j]
                th[k] += h
                grad[:, j] = (c_fn(th) - c0) / (h / sc[j])
        G = grad[ct > limit]  # keep the broken components where they are (first order)
        M = np.ascontiguousarray(G @ G.T + 1e-12 * np.trace(G @ G.T) * np.eye(len(G)))
        y, Lm = np.empty((len(G), 1)), np.empty_like(M)
        if cholesky_solve(M, np.ascontiguousarray((G @ dz)[:, None]), Lm, y):
            dz = dz - G.T @ y[:, 0]
        trial[idx] = np.clip((z + dz) * sc, blo[idx], bhi[idx])
    for _ in range(10):
        if (c_fn(trial) <= limit).all():
            return trial, grad
        dz = 0.5 * dz
        trial[idx] = np.clip((z + dz) * sc, blo[idx], bhi[idx])
    return theta.copy(), grad


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
        P = lambda th: _plant(self.vehicle, self.specs, th)  # noqa: E731
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

    def minimise(self, theta0, free, iterations, bounds=None, pin=None, constraint=None):
        """Levenberg–Marquardt on the ``free`` parameters, each step solved within the bounds (the plausible
        ones, or ``bounds``); stops when the loss falls by less than 1e-5 of itself (far below its sampling
        noise).  ``pin``: ``(Q, theta_pin)``, a quadratic penalty ``½ (z − z_pin)ᵀ Q (z − z_pin)`` in the scaled
        parameters z = θ / scale (all of them): the unconstrained directions held at their one-step values.
        ``constraint``: ``(c, limit)``, ``c(θ)`` a vector every iterate keeps at or below ``limit`` (from a start
        that keeps it): a trial step that breaks it is projected onto the tangent plane of the components it
        breaks (their finite-difference gradients at the current point), then shortened (halved, up to 10
        times) until it keeps it."""
        from ..identification.box_qp import box_qp

        blo, bhi = bounds if bounds is not None else (self.lo, self.hi)
        theta = np.clip(theta0, blo, bhi)
        idx = np.flatnonzero(free)
        if not idx.size:
            return theta, 0, "nothing to refine"
        sc, lo, hi = self.scale[idx], blo[idx] / self.scale[idx], bhi[idx] / self.scale[idx]
        Q, zp = (pin[0][np.ix_(idx, idx)], pin[1][idx] / sc) if pin is not None else (None, None)
        penalty = (lambda z: 0.5 * float((z - zp) @ Q @ (z - zp))) if Q is not None else (lambda z: 0.0)  # noqa: E731
        mu, it, stopped = 1e-3, 0, f"the iteration limit ({iterations})"
        while it < iterations:
            it += 1
            cost, A, Ad, g, _, _ = self.normal(theta, idx)
            H = _psd(A - Ad, A)
            z = theta[idx] / sc
            cost += penalty(z)
            if Q is not None:
                H, g = H + Q, g + Q @ (z - zp)
            D = np.maximum(np.diag(H), 1e-12 * max(np.diag(H).max(), 1e-300))
            new = cost
            grad = None  # the constraint's gradient at theta (in z), computed when first needed
            for _ in range(10):
                dz = box_qp(H + mu * np.diag(D), -g, lo - z, hi - z)
                trial = theta.copy()
                trial[idx] = np.clip((z + dz) * sc, blo[idx], bhi[idx])
                if constraint is not None:
                    trial, grad = _kept(constraint, theta, trial, z, dz, idx, sc, (blo, bhi), grad)
                new = self.cost(trial) + penalty(trial[idx] / sc)
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

    def step(self, theta, free, moved, normal, bounds=None):
        """One Levenberg–Marquardt step from ``theta`` on the ``free`` parameters from the normal equations
        ``normal`` (of :meth:`normal` for the parameters ``moved``, a superset): the first damping the training
        loss accepts (``theta`` itself if none does)."""
        from ..identification.box_qp import box_qp

        blo, bhi = bounds if bounds is not None else (self.lo, self.hi)
        cost, A, Ad, g, _, _ = normal
        sel = np.flatnonzero(free[moved])
        idx = moved[sel]
        A, Ad, g = A[np.ix_(sel, sel)], Ad[np.ix_(sel, sel)], g[sel]
        H = _psd(A - Ad, A)
        sc = self.scale[idx]
        z, lo, hi = theta[idx] / sc, blo[idx] / sc, bhi[idx] / sc
        D = np.maximum(np.diag(H), 1e-12 * max(np.diag(H).max(), 1e-300))
        mu = 1e-3
        for _ in range(12):
            dz = box_qp(H + mu * np.diag(D), -g, lo - z, hi - z)
            trial = theta.copy()
            trial[idx] = np.clip((z + dz) * sc, blo[idx], bhi[idx])
            if self.cost(trial) < cost:
                return trial
            mu *= 4
        return theta

    def covariance(self, theta, free=None):
        """``(idx, H, B)``: the parameters off their bounds, the Gauss–Newton Hessian (corrected for the
        input noise where positive definite) and the long-run covariance B of the windows' own gradients
        (Bartlett weights over ``lag`` neighbouring windows of the same piece: overlapping windows share
        samples, and a rollout's errors stay correlated beyond its own horizon), in the scaled parameters."""
        at_bound = (theta <= self.lo + 1e-9 * self.scale) | (theta >= self.hi - 1e-9 * self.scale)
        idx = np.flatnonzero(~at_bound & (np.ones(len(theta), bool) if free is None else free))
        if not idx.size:
            return idx, np.zeros((0, 0)), np.zeros((0, 0))
        _, A, Ad, _, G, _ = self.normal(theta, idx)
        B = np.zeros((idx.size, idx.size))
        L = self.stack.lag
        for k in np.unique(self.stack.piece):  # pieces in order, lags in order: a fixed summation order
            Gk = G[self.stack.piece == k]
            B += Gk.T @ Gk
            for lag in range(1, min(L, len(Gk) - 1) + 1):
                C = Gk[:-lag].T @ Gk[lag:]
                B += (1.0 - lag / (L + 1.0)) * (C + C.T)
        return idx, np.ascontiguousarray(_psd(A - Ad, A)), B

    def sandwich(self, cov) -> tuple:
        """``(idx, Σ)``: the sandwich ``A⁻¹ B A⁻¹`` of :meth:`covariance`'s result in parameter units (an empty
        matrix where ``A`` is not positive definite)."""
        idx, Hm, B = cov
        p = idx.size
        if not p:
            return idx, np.zeros((0, 0))
        X, Lm, Y = np.empty((p, p)), np.empty((p, p)), np.empty((p, p))
        if not cholesky_solve(Hm, np.ascontiguousarray(B), Lm, X):
            return idx[:0], np.zeros((0, 0))
        cholesky_solve(Hm, np.ascontiguousarray(X.T), Lm, Y)
        Y = 0.5 * (Y + Y.T)
        return idx, Y * np.outer(self.scale[idx], self.scale[idx])

    def stderr(self, theta, cov=None, free=None) -> np.ndarray:
        """Standard errors (parameter units) from the Gauss–Newton sandwich ``A⁻¹ B A⁻¹`` (:meth:`covariance`);
        NaN at a bound or where not identified."""
        idx, Hm, B = cov if cov is not None else self.covariance(theta, free)
        se = np.full(len(theta), np.nan)
        if not idx.size:
            return se
        p = idx.size
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
              "refined": (_plant(vehicle, specs, theta), MODEL)}
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
    out = [x for p in r.parameters if p.refined and (x := _parameter_sentence(p))]
    for p in r.parameters:
        lo, hi = p.physical
        if not lo <= p.written <= hi:
            out.append(f"{p.label} = {_g(p.total(p.written))}, the one-step estimate the diagnosis named, lies outside "
                       f"its physical range [{_g(p.total(lo))}, {_g(p.total(hi))}]; the refinement does not move it.")
    agree = [p.label for p in r.parameters
             if p.refined and p.in_range and not p.disagree and not p.bound_hit and p.z is not None]
    if agree:
        out.append(f"Within {DISAGREE_Z:g} standard errors of each other: {', '.join(agree)}.")
    out += _admission_sentences(r)
    for d in r.unconstrained:
        out.append(f"The data cannot fix {d.words()}: this combination stays at its one-step values in the written "
                   "model (unconstrained).")
    out += _ablation_words(r)
    if r.diverged:
        out.append(f"{r.diverged} of the {r.windows} training windows diverge under the written model; each is scored "
                   "as qr evaluate scores it (its last sane state held).")
    return out + _window_sentences(r)


def _parameter_sentence(p) -> str | None:
    """What the rollout wants of a refined parameter against the one-step fit, when that is worth a sentence
    (outside its physical range, standard errors apart, on a plausible bound)."""
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
        kept = (f"it is held at the one-step value {_g(p.total(p.one_step))} in the written model"
                if p.written == p.one_step else
                f"the written model has {_g(p.total(p.written))}, within its range (the held-out windows chose "
                "the range's end over the one-step value)")
        return (f"The rollout wants {p.label} = {_g(p.total(p.rollout))}{times}, {side}{why}); {kept}. "
                + _meaning(p, ratio, True))
    if p.disagree:
        se = f" ± {_g(p.rollout_se)}" if p.rollout_se else ""
        se1 = f" ± {_g(p.one_step_se)}" if p.one_step_se else " (the vehicle file's, no standard error)"
        return (f"{p.label}: the rollout wants {_g(p.total(p.rollout))}{se}, the one-step fit "
                f"{_g(p.total(p.one_step))}{se1}: {abs(p.z):.1f} standard errors apart{times}. "
                + _meaning(p, ratio, False))
    if p.bound_hit and p.total(p.rollout) == p.total(p.one_step):
        return (f"{p.label}: the rollout's optimum is the one-step value, its {p.bound_hit} bound "
                f"{_g(p.total(p.rollout))}.")
    if p.bound_hit:
        return (f"{p.label}: the rollout's optimum lies on its {p.bound_hit} plausible bound "
                f"{_g(p.total(p.rollout))}{times}: it wants a value the catalog's range rules out; held at the "
                f"one-step value {_g(p.total(p.one_step))} in the written model. " + _meaning(p, ratio, True))
    return None


def _admission_sentences(r: Refinement) -> list[str]:
    """Per group of parameters the refinement tried beside the others: the held-out loss with and without it."""
    out = []
    for g, (a, b, ok) in r.admission.items():
        if g.startswith("beyond"):
            if a is not None and b is not None:
                out.append(f"Parameters wanted beyond their physical range: held at their one-step values the held-out "
                           f"windows' loss is {a:.4g}, fitted within their ranges {b:.4g}; the written model "
                           + ("fits them within their ranges." if ok else "holds them."))
            continue
        if a is None:
            out.append(f"{g}: not tried (no held-out windows to judge it on).")
        else:
            out.append(f"{g}: fitted beside the others it takes the held-out windows' loss from {a:.4g} to {b:.4g} "
                       f"({100 * (b / a - 1):+.1f} %): " + ("admitted." if ok else
                                                            f"not admitted (it must lower it by {100 * ADMIT_GAIN:g} %)."))
    return out


def _window_sentences(r: Refinement) -> list[str]:
    """The extended (one-step) and the refined model's ratios to rate_frozen at h = H on the training and the
    held-out windows."""
    out, H = [], r.horizon
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


def _ablation_words(r: Refinement) -> list[str]:
    """The body-rate error at H each refined term removes (held-out windows where there are, else training)."""
    rows = {a.term: a for a in r.ablation}
    if "refined" not in rows:
        return []
    side = "held_out" if rows["refined"].held_out is not None else "training"
    w = QUANTITIES.index("w")
    full, one = getattr(rows["refined"], side)[w], getattr(rows["one-step"], side)[w]
    parts = [f"{a.term} {getattr(a, side)[w] - full:+.3g}" for a in r.ablation if a.term not in ("refined", "one-step")]
    if not parts:
        return []
    return [f"Body-rate error at h = {r.horizon} on the {side.replace('_', '-')} windows: {one:.3g} rad/s one-step, "
            f"{full:.3g} refined; with one term back at its one-step values (rad/s added): {', '.join(parts)}."]


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
    if p.effect == "motor_imbalance":
        return ("One rotor's thrust and drag torque per squared speed differ from the others' over the horizon: "
                "a rotor or propeller off, or its speed sensor's scale.")
    if p.effect == "cg_offset":
        return "The thrust's line passes beside the CG: its torque, integrated over the horizon, moves the rates."
    if p.effect == "rotor_torque_gains":
        return ("One rotor's yaw torque per squared speed differs from the others' beyond its thrust's share: "
                "a propeller whose torque and thrust do not scale together.")
    if p.effect == "rotor_inertia":
        return ("The rotors' angular momentum: a gyroscopic roll/pitch moment with the body rate and a yaw reaction "
                "whenever the rotors change speed.")
    if p.effect == "flapping_pitch_ratio":
        return "The blade-flapping moment is not the same about pitch as about roll (the frame or rotor layout)."
    if p.effect == "actuator_delay":
        return ("A lag between the logged rotor speeds and the forces and torques they make, which the one-step fit "
                "does not see: rotor or logging latency, or start states (filtered estimates) that lag the truth."
                if up else "Less delay than the one-step fit found.")
    return (f"Over the horizon the {p.effect} parameter also absorbs what the model lacks there; the one-step value "
            "is what the force and torque balance measures sample by sample.")


# ---- the report's section ----------------------------------------------------------------------------

PROPERTY_UNITS = {"rotor_inertia": "kg m²"}  # the others are ratios to the file's


def _unit_of(p: dict) -> str:
    """A refinement row's unit ("–" for a ratio): J in kg m² (the file's plus dJ), a catalog parameter's, a
    property's."""
    if p["effect"] == "inertia_error":
        return "kg m²"
    u = unit(p["effect"], p["parameter"]) or PROPERTY_UNITS.get(p["effect"], DIMENSIONLESS)
    return "–" if u == DIMENSIONLESS else u


def report_lines(block: dict) -> list[str]:
    """``report.md``'s section on the refinement (from ``diagnosis.json``'s ``refine`` block)."""
    H = block["horizon"]
    lines = ["## Refinement by simulation error (`diagnose.refine=rollout`)", "",
             f"The named effects' parameters and the vehicle's own coefficients adjusted to minimise the "
             f"{H}-step rollout error on {block['windows']} training windows (every {block['stride']}th start), "
             f"from the one-step (equation-error) estimates; {block['iterations']} Levenberg–Marquardt iterations "
             f"({block['stopped']}), {block['wall_s']:.1f} s. Standard errors: {block['covariance']}.", "",
             "| parameter | unit | one-step ± s.e. | rollout ± s.e. | z | physical range | written |",
             "|---|---|---:|---:|---:|---|---:|"]
    fmt = lambda x: "–" if x is None else f"{x:.4g}"  # noqa: E731
    for p in block["parameters"]:
        ref = p["reference"] if p["effect"] == "inertia_error" else 0.0
        lo, hi = p["physical_range"]
        total = lambda x: None if x is None else ref + x  # noqa: E731
        one = fmt(total(p["one_step"])) + (f" ± {p['one_step_stderr']:.2g}" if p["one_step_stderr"] else "")
        roll = fmt(total(p["rollout"])) + (f" ± {p['rollout_stderr']:.2g}" if p["rollout_stderr"] else
                                           (f" (at the {p['bound_hit']} bound)" if p["bound_hit"] else ""))
        if not p.get("refined", True):
            roll = "not admitted"
        lines.append(f"| {p['label']}{'' if p['named'] else ' (vehicle)'} | {_unit_of(p)} | {one} | {roll} | "
                     f"{fmt(p['z']) if p['z'] is not None else '–'} | [{total(lo):.3g}, {total(hi):.3g}] | "
                     f"{fmt(total(p['written']))}" + ("" if p["in_range"] else " (out of range: one-step kept)"
                                                      if p["written"] == p["one_step"] else " (wanted out of range: "
                                                      "fitted within it)") + " |")
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
    if block.get("unconstrained"):
        lines += ["Directions the data cannot fix (unconstrained; held at their one-step values in the written model):",
                  "", "| direction (unit, in physical ranges) | curvature / largest | s.e. (ranges) |", "|---|---:|---:|"]
        for d in block["unconstrained"]:
            terms = " ".join(f"{w:+.2f} {k}" for k, w in d["parameters"].items())
            lines.append(f"| {terms} | {d['curvature_ratio']:.2g} | {fmt(d['stderr_in_ranges'])} |")
        lines.append("")
    abl = block.get("ablation", {}).get("rows") or []
    if abl:
        lines += [f"What each refined term removes: MAE at h = {H} with the term back at its one-step values "
                  "(training windows | held-out windows):", "",
                  "| model | " + " | ".join(QUANTITIES) + " | " + " | ".join(f"held-out {q}" for q in QUANTITIES) + " |",
                  "|---|" + "---:|" * (2 * len(QUANTITIES))]
        for a in abl:
            name = a["term"] if a["term"] in ("refined", "one-step") else f"refined without {a['term']}"
            tr = a["training_mae_at_H"] or [None] * 4
            ho = a["held_out_mae_at_H"] or [None] * 4
            lines.append(f"| {name} | " + " | ".join(fmt(x) for x in tr) + " | " + " | ".join(fmt(x) for x in ho) + " |")
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
    balance = balance_rows(states_list, owner, windows, dcfg.trim_s)
    settings = RefineSettings(horizon=ecfg.horizon, stride=dcfg.refine_stride,
                              iterations=dcfg.refine_iterations, block_s=dcfg.block_s, delay=dcfg.refine_delay,
                              exclude=tuple(dcfg.exclude), rotors=dcfg.refine_rotors, beyond=dcfg.refine_beyond)
    return refine(train, held_out, vehicle, effects, settings, noise, seed, log, balance)
