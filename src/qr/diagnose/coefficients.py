"""What the named effects say about the vehicle file's own numbers, where the data can tell.

A gross factor (``GROSS``) on a C_T, C_Q, inertia or mass is stated only where the coefficient is identified
(:func:`evidence`, :func:`coefficient_checks`: no near-collinear partner, stable over the two halves,
consistent with the hover thrust, not a rate damping); what fails is listed as unresolved, with why, never
stated.  The rules: docs/diagnose.md "How it decides".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..effects import CATALOG
from ..identification.normal_equations import Columns, fit, inflation

GROSS = 1.5  # a factor this far from 1, either way, is a wrong number in the file, not a small correction
DAMPING = "rotor_drag_moment"  # the yaw-rate damping a C_Q factor is checked against
RATE_DAMPING = "rate_damping"  # the body-rate damping an inertia factor is checked against (qr.effects.CHECK_TERMS)
CHECKED_AGAINST = {"yaw_torque_gain": DAMPING, "inertia_error": RATE_DAMPING}
VIF_MAX = 10.0  # variance inflation above which a parameter is a combination with another, not itself
HOVER_TOL = 1.25  # a C_T or mass factor may disagree with the log's hover balance by this factor at most


@dataclass(frozen=True)
class Evidence:
    """What the training data say of one named effect's parameters (one-step fit)."""

    inflation: list[float]  # per parameter: variance inflation in the named set's joint fit
    partner: list[str | None]  # per parameter: the effect it is most collinear with
    halves: tuple[list[float], list[float]]  # the parameters (file units) fitted on each half of the blocks
    # the parameters (file units) fitted with the damping of CHECKED_AGAINST beside the named set, where the
    # statistics hold it and the set did not name it (else None)
    with_damping: list[float] | None = None


def evidence(stats, named: list[str], fixed=()) -> dict[str, Evidence]:
    """:class:`Evidence` of each effect of ``named`` fitted by the one-step fit (not those in ``fixed``)."""
    own = [e for e in named if e not in fixed]
    if not own:
        return {}
    cols = Columns.of(own)
    vif = inflation(stats, own)
    idx = stats.cols.index(own)
    G = stats.G.sum(0)[np.ix_(idx, idx)]
    d = np.sqrt(np.maximum(np.diag(G), 1e-300))
    corr = G / np.outer(d, d)
    owner = [e for e in own for _ in CATALOG[e].params]
    B = stats.blocks
    halves = [fit(stats, own, np.arange(B // 2)), fit(stats, own, np.arange(B // 2, B))] if B >= 4 else None
    damped = {}
    for e in own:
        c = CHECKED_AGAINST.get(e)
        if c in stats.cols.effects and c not in named:
            damped[e] = fit(stats, own + [c])[cols.slices[e]]
    out = {}
    for e in own:
        sl = cols.slices[e]
        partner = []
        for j in range(sl.start, sl.stop):
            others = [k for k in range(len(owner)) if owner[k] != e]
            partner.append(owner[max(others, key=lambda k: abs(corr[j, k]))] if others else None)
        neutral = np.asarray(CATALOG[e].neutral, float)
        out[e] = Evidence([float(v) for v in vif[sl]], partner,
                          tuple((h[sl] + neutral).tolist() for h in halves) if halves else ([], []),
                          (damped[e] + neutral).tolist() if e in damped else None)
    return out


def _factors(name: str, p: dict, se: dict, vehicle):
    """(vehicle-file key, symbol, file value, factor true/file, s.e. of the factor, parameter) of a
    coefficient effect."""
    if name == "thrust_gain":
        yield "thrust_coeff", "C_T", vehicle.thrust_coeff, p["gain"], se.get("gain"), "gain"
    elif name == "yaw_torque_gain":
        yield "torque_coeff", "C_Q", vehicle.torque_coeff, p["gain"], se.get("gain"), "gain"
    elif name == "mass_error":
        m = vehicle.mass
        yield "mass", "m", m, 1 + p["dm"] / m, (se.get("dm") or 0) / m, "dm"
    elif name == "inertia_error":
        for i, ax in enumerate(("xx", "yy", "zz")):
            J = float(vehicle.inertia[i])
            yield f"inertia[{i}]", f"J{ax}", J, 1 + p[f"dJ{ax}"] / J, (se.get(f"dJ{ax}") or 0) / J, f"dJ{ax}"


def _gross(factor: float) -> int:
    """+1 for a factor of GROSS or more, -1 for 1/GROSS or less, 0 between."""
    return 1 if factor >= GROSS else -1 if factor <= 1 / GROSS else 0


def _why_not(name, key, sym, factor, param, ev: Evidence | None, vehicle, hover_ratio) -> str | None:
    """Why a gross factor of ``sym`` is not identified by these data; None if it is."""
    if ev is None:
        return "it is not fitted by the one-step fit (its stability cannot be checked)"
    j = list(CATALOG[name].params).index(param)
    if ev.inflation[j] >= VIF_MAX:
        return (f"it trades off against {ev.partner[j]} (variance inflation {ev.inflation[j]:.0f}): the data fix "
                f"only a combination of the two")
    if ev.halves[0]:
        half = []
        for h in ev.halves:
            hp = dict(zip(CATALOG[name].params, h))
            half.append([f for k, _, _, f, _, q in _factors(name, hp, {}, vehicle) if k == key][0])
        if not all(_gross(f) == _gross(factor) for f in half):
            return (f"the first and the second half of the training data give x{half[0]:.3g} and x{half[1]:.3g}: "
                    f"not the same statement")
    if ev.with_damping is not None:
        hp = dict(zip(CATALOG[name].params, ev.with_damping))
        damped = [f for k, _, _, f, _, _ in _factors(name, hp, {}, vehicle) if k == key][0]
        if _gross(damped) != _gross(factor):
            if name == "yaw_torque_gain":
                return (f"fitted beside a yaw-rate damping ({DAMPING}: the rotor drag's moment at the hubs) it is "
                        f"x{damped:.3g}: the yaw torque grows with the yaw rate, which a C_Q error does not")
            return (f"fitted beside a rate damping (a torque -c ω opposing the body rate, no catalog effect) it is "
                    f"x{damped:.3g}: the torque grows with the body rate, which an inertia error does not")
    if key in ("thrust_coeff", "mass") and hover_ratio is not None and np.isfinite(hover_ratio):
        # hover: C_T-thrust x gain = (m + dm) g, so the file's rotor map gives m g x (mass factor / gain)
        predicted = 1 / factor if key == "thrust_coeff" else factor
        if not 1 / HOVER_TOL <= hover_ratio / predicted <= HOVER_TOL:
            return (f"the log's hover balance contradicts it: by the file the rotors give {hover_ratio:.3g} x m g "
                    f"in flight, where x{factor:.3g} would make it {predicted:.3g} x m g")
    return None


@dataclass(frozen=True)
class FileFactor:
    """A vehicle-file number the named effects put off by ``GROSS`` or more: stated (``statement``) or, where
    the data do not identify it, not (``why``)."""

    key: str  # the vehicle file's key (``inertia[2]``: an element)
    file_value: float
    estimate: float  # file_value x factor
    factor: float
    factor_stderr: float
    effect: str  # the named effect that puts it off
    statement: str | None = None
    why: str | None = None

    def record(self) -> dict:
        """``diagnosis.json``'s ``vehicle_file`` (or ``vehicle_file_unresolved``) entry."""
        return {"key": self.key, "file_value": self.file_value, "estimate": self.estimate, "factor": self.factor,
                "factor_stderr": self.factor_stderr, "effect": self.effect,
                **({"why": self.why} if self.why is not None else {"statement": self.statement})}


def coefficient_checks(effects: list[dict], vehicle, vehicle_path, evidence_of: dict | None = None,
                       hover_ratio: float | None = None) -> tuple[list[FileFactor], list[FileFactor]]:
    """(statements, unresolved): one statement per vehicle-file number the named effects put off by
    ``GROSS`` or more *and* the data identify; the other gross factors, each with why it is not said."""
    said, unresolved = [], []
    for e in effects:
        for key, sym, value, factor, se, param in _factors(e["name"], e["parameters"], e.get("stderr", {}), vehicle):
            if not _gross(factor):
                continue
            why = _why_not(e["name"], key, sym, factor, param, (evidence_of or {}).get(e["name"]), vehicle,
                           hover_ratio)
            entry = (key, value, value * factor, factor, se, e["name"])
            if why:
                unresolved.append(FileFactor(*entry, why=f"{sym} ({key}) x{factor:.3g} not stated: {why}"))
                continue
            x, word = (factor, "small") if factor > 1 else (1 / factor, "large")
            if key == "torque_coeff":  # J_z α_z = C_Q-torque: the data fix the ratio
                statement = (f"C_Q / Jzz (torque_coeff / inertia[2]) in {vehicle_path} looks x{x:.2g} too {word}: "
                             f"the data give C_Q / Jzz = {value * factor / vehicle.inertia[2]:.4g}, the file says "
                             f"{value / vehicle.inertia[2]:.4g} (only the ratio is identified)")
            else:
                statement = (f"{sym} ({key}) in {vehicle_path} looks x{x:.2g} too {word}: the data give "
                             f"{value * factor:.4g}, the file says {value:.4g}")
                if key == "inertia[2]":
                    statement += f" (only C_Q / Jzz is identified: equally, C_Q x{1 / factor:.2g})"
            # a confounded partner (C_T against a mass error where the torque rows cannot arbitrate): the pair
            alike = [c for c in e.get("confounded_with", []) if {e["name"], c} != {"inertia_error", "yaw_torque_gain"}]
            if alike:
                statement += f" (or, confounded with it: {', '.join(alike)})"
            said.append(FileFactor(*entry, statement=statement))
    return said, unresolved
