"""How far to trust a rollout: uncertainty bands around a model's predictions (docs/evaluate.md, "Bands").

The draws of an ensemble of plants (refined parameters from the sandwich covariance, or a residual
ensemble's members) flown beside the model give radii r₅₀, r₉₀ per window and quantity, scaled per quantity
on the validation data (:func:`calibrate`); the band source of a vehicle file: :func:`source_of`.  The same
numbers on any thread count (one rollout loop, compiled draws, no BLAS).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TypeAlias

import numba as nb
import numpy as np

from .rollout import MODEL, QUANTITIES, Windows, roll_window
from .plant_state import N_RB, P_DELAY, P_MARKER, X_POS, X_QUAT, X_RATE, X_VEL
from .frames_compiled import quat_angle

SCHEMA = "qr.bands/1"
LEVELS = (0.5, 0.9)
CALIBRATE_LEVEL = 0.9  # the level the scale is chosen for, on validation data
SUFFIX = ".bands.json"


# ---- the compiled spread --------------------------------------------------------------------------

@nb.njit(cache=True)
def _quantile(vals, n, level):
    """The ``level`` quantile (linear interpolation) of the first ``n`` values of ``vals`` (sorted in place)."""
    a = np.sort(vals[:n])
    pos = level * (n - 1)
    lo = int(math.floor(pos))
    hi = min(lo + 1, n - 1)
    return a[lo] + (pos - lo) * (a[hi] - a[lo])


@nb.njit(cache=True)
def _dist(a, b, q):
    if q == 2:
        return quat_angle(a[X_QUAT], b[X_QUAT])
    o = X_POS.start if q == 0 else (X_VEL.start if q == 1 else X_RATE.start)
    return math.sqrt((a[o] - b[o]) ** 2 + (a[o + 1] - b[o + 1]) ** 2 + (a[o + 2] - b[o + 2]) ** 2)


@nb.njit(cache=True, parallel=True)
def _spread(t, X0, Us, starts, H, Ps, tp, tq, tv, tw, err, r50, r90):
    """Per start (its own row: no shared sums): the centre's (plant 0) error at h = H against the truth
    (NaN where the truth is missing or the piece ends) and the draws' (plants 1 …) radii around it."""
    for s in nb.prange(len(starts)):
        _spread_at(s, t, X0, Us, starts, H, Ps, tp, tq, tv, tw, err, r50, r90)


@nb.njit(cache=True)
def _spread_at(s, t, X0, Us, starts, H, Ps, tp, tq, tv, tw, err, r50, r90):
    """:func:`_spread`'s start ``s`` (a kernel of its own: numba's parallel analysis takes no slice constant)."""
    D = Ps.shape[0] - 1
    i = starts[s]
    x, xn, xs, k = np.empty(N_RB), np.empty(N_RB), np.empty(N_RB), np.empty((4, N_RB))
    out = np.empty((H, N_RB))
    centre = np.empty(N_RB)
    steps, _ = roll_window(t, X0, Us[0], i, H, Ps[0], MODEL, Ps[0, P_MARKER].copy(), out, k, xs, xn, x)
    for q in range(4):
        err[s, q] = np.nan
        r50[s, q] = np.nan
        r90[s, q] = np.nan
    if steps < H:
        return
    centre[:] = out[H - 1]
    j = i + H
    p, v, w = X_POS.start, X_VEL.start, X_RATE.start
    if np.isfinite(tp[j, 0]):
        err[s, 0] = math.sqrt((centre[p] - tp[j, 0]) ** 2 + (centre[p + 1] - tp[j, 1]) ** 2
                              + (centre[p + 2] - tp[j, 2]) ** 2)
    if np.isfinite(tv[j, 0]):
        err[s, 1] = math.sqrt((centre[v] - tv[j, 0]) ** 2 + (centre[v + 1] - tv[j, 1]) ** 2
                              + (centre[v + 2] - tv[j, 2]) ** 2)
    if np.isfinite(tq[j, 0]):
        err[s, 2] = quat_angle(tq[j], centre[X_QUAT])
    if np.isfinite(tw[j, 0]):
        err[s, 3] = math.sqrt((centre[w] - tw[j, 0]) ** 2 + (centre[w + 1] - tw[j, 1]) ** 2
                              + (centre[w + 2] - tw[j, 2]) ** 2)
    dev = np.empty((4, D))
    for d in range(D):
        P = Ps[d + 1]
        roll_window(t, X0, Us[d + 1], i, H, P, MODEL, P[P_MARKER].copy(), out, k, xs, xn, x)
        for q in range(4):
            dev[q, d] = _dist(out[H - 1], centre, q)
    for q in range(4):
        r50[s, q] = _quantile(dev[q], D, 0.5)
        r90[s, q] = _quantile(dev[q], D, 0.9)


@dataclass(frozen=True)
class Spread:
    """Per scored start (pieces concatenated): the centre's error at h = H and the draws' radii, (S, 4) each
    (p m, v m/s, R rad, ω rad/s; NaN where the truth is missing or the window incomplete)."""

    err: np.ndarray
    r50: np.ndarray
    r90: np.ndarray
    t: np.ndarray  # (S,) the start times, s
    piece: np.ndarray  # (S,) the piece each start belongs to

    @staticmethod
    def join(parts: list["Spread"]) -> "Spread":
        if not parts:
            z = np.zeros((0, 4))
            return Spread(z, z, z, np.zeros(0), np.zeros(0, int))
        return Spread(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("err", "r50", "r90", "t", "piece")))


def spread(pieces: list[Windows], Ps: np.ndarray, H: int, first_piece: int = 0) -> Spread:
    """The :class:`Spread` of the plants ``Ps`` (row 0 the centre, the others the draws) over the scored
    starts of ``pieces`` (each plant's actuator delay applied to its own inputs)."""
    Ps = np.ascontiguousarray(np.atleast_2d(np.asarray(Ps, float)))
    if Ps.shape[0] < 3:
        raise ValueError("a band needs at least two draws beside the centre")
    parts = []
    for n, w in enumerate(pieces):
        starts = np.flatnonzero(w.ok)
        starts = np.ascontiguousarray(starts[starts + H < len(w.t)]).astype(np.int64)
        S = len(starts)
        err, r50, r90 = np.empty((S, 4)), np.empty((S, 4)), np.empty((S, 4))
        if S:
            cache: dict = {}
            Us = np.ascontiguousarray(np.stack([cache.setdefault(float(P[P_DELAY]), w.inputs(P)) for P in Ps]))
            _spread(w.t, w.X0, Us, starts, H, Ps, w.tp, w.tq, w.tv, w.tw, err, r50, r90)
        parts.append(Spread(err, r50, r90, w.t[starts], np.full(S, first_piece + n)))
    return Spread.join(parts)


# ---- scale and coverage ------------------------------------------------------------------------------

def calibrate(sp: Spread, level: float = CALIBRATE_LEVEL) -> Scale:
    """One scale per quantity: the ``level`` quantile over the samples of error / r_level (r₅₀ for 0.5, else
    r₉₀), so that the scaled band covers ``level`` of them (None where no sample has both, or the radius is 0
    too often)."""
    out = {}
    radii = sp.r50 if level == 0.5 else sp.r90
    for k, q in enumerate(QUANTITIES):
        e, r = sp.err[:, k], radii[:, k]
        ok = np.isfinite(e) & np.isfinite(r)
        if not ok.any():
            out[q] = None
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(r[ok] > 0, e[ok] / r[ok], np.where(e[ok] > 0, np.inf, 0.0))
        ratio = np.sort(ratio)
        hi = min(int(math.ceil(level * (len(ratio) - 1))), len(ratio) - 1)
        # (a radius of 0 under an error at the quantile: no scale makes that band cover)
        out[q] = float(np.quantile(ratio, level)) if math.isfinite(ratio[hi]) else None
    return out


def calibrate_levels(sp: Spread) -> tuple[Scale, Scale]:
    """The scales of the 90 % and of the 50 % band (:func:`calibrate` at each level): the draws' spread need
    not have the errors' shape (a few diverging draws widen r₉₀ far more than r₅₀), so one scale cannot make
    both bands cover their share."""
    return calibrate(sp, CALIBRATE_LEVEL), calibrate(sp, 0.5)


def coverage(sp: Spread, scale: Scale | None, scale50: Scale | None = None) -> dict:
    """Per quantity: the share of samples whose truth lies inside the 50 % and 90 % bands (radii × ``scale``, the
    50 % radii × ``scale50`` where it has the quantity; 1 where none), the samples, the median scaled radii; and
    the mean of the quantities' shares."""
    by = {}
    for k, q in enumerate(QUANTITIES):
        s, s50 = level_scales(scale, scale50, q)
        e = sp.err[:, k]
        ok = np.isfinite(e) & np.isfinite(sp.r90[:, k])
        n = int(ok.sum())
        row = {"samples": n, "scale": s, "scale50": s50}
        for lev, r, f in ((50, sp.r50[:, k], s50), (90, sp.r90[:, k], s)):
            row[f"coverage{lev}"] = float(np.mean(e[ok] <= f * r[ok])) if n else None
            row[f"median_radius{lev}"] = float(np.median(f * r[ok])) if n else None
        by[q] = row
    mean = lambda key: (float(np.mean([by[q][key] for q in QUANTITIES if by[q][key] is not None]))  # noqa: E731
                        if any(by[q][key] is not None for q in QUANTITIES) else None)
    return {"coverage90": mean("coverage90"), "coverage50": mean("coverage50"), "by_quantity": by}


def level_scales(scale: Scale | None, scale50: Scale | None, q: str) -> tuple[float, float]:
    """``(s₉₀, s₅₀)`` of quantity ``q``: 1 where unscaled; the 50 % band's the 90 % one's where it has none (a
    source written before the levels had scales of their own)."""
    s = (scale or {}).get(q)
    s = 1.0 if s is None else float(s)
    s50 = (scale50 or {}).get(q)
    return s, s if s50 is None else float(s50)


# ---- parameter draws (deterministic: compiled Cholesky and products) ---------------------------------

@nb.njit(cache=True)
def _correlate(Z, L, out):
    D, n = Z.shape
    for d in range(D):
        for a in range(n):
            s = 0.0
            for b in range(a + 1):
                s += L[a, b] * Z[d, b]
            out[d, a] = s


DRAW_BATCHES = 200  # batches of candidates tried before the draws still missing are clipped instead


def draw_parameters(written: np.ndarray, cov: np.ndarray, bounds: np.ndarray, draws: int, seed: int) -> np.ndarray:
    """``draws`` parameter vectors (draws, n): ``written`` plus N(0, ``cov``) restricted to the box ``bounds``
    (n, 2) (a draw beyond a physical bound would fly a vehicle that cannot exist).  A candidate outside is
    drawn again, not clipped: clipping one coordinate breaks the correlations that keep a draw's terms
    consistent (a thrust gain against a vertical force, say), and flies vehicles the covariance excludes.
    Candidates come in batches of ``draws`` from one seeded stream, kept in order (without a candidate
    outside, the first batch: the plain draws); after ``DRAW_BATCHES`` batches the rest are clipped."""
    from .linalg_compiled import cholesky

    written = np.asarray(written, float)
    n = len(written)
    cov = np.ascontiguousarray(np.asarray(cov, float).reshape(n, n))
    L = np.zeros((n, n))
    jitter = 0.0
    scale = float(np.max(np.abs(np.diag(cov)))) if n else 0.0
    for _ in range(8):  # a covariance with a numerically null direction: the smallest jitter that factors
        if cholesky(np.ascontiguousarray(cov + jitter * np.eye(n)), L):
            break
        jitter = max(jitter * 100.0, 1e-12 * max(scale, 1e-300))
    else:
        L = np.diag(np.sqrt(np.maximum(np.diag(cov), 0.0)))
    L = np.ascontiguousarray(np.tril(L))
    b = np.asarray(bounds, float).reshape(n, 2)
    rng = np.random.default_rng(seed)
    kept, have, X = [], 0, np.empty((draws, n))
    for _ in range(DRAW_BATCHES):
        _correlate(np.ascontiguousarray(rng.standard_normal((draws, n))), L, X)
        X += written[None, :]
        ok = X[np.all((X >= b[:, 0]) & (X <= b[:, 1]), axis=1)][:draws - have]
        kept.append(ok.copy())
        have += len(ok)
        if have == draws:
            break
    else:
        kept.append(np.clip(X[:draws - have], b[:, 0], b[:, 1]))
    return np.concatenate(kept) if kept else np.empty((0, n))


def perturbed(vehicle, params: list[dict], values) -> tuple:
    """``(vehicle, effects)`` with each parameter of ``params`` (``{effect, parameter, shared_with}``, as the
    refinement's block names them) set to ``values``: a vehicle key (``rotor_torque_gains`` by index,
    ``rotor_inertia``, ``flapping_pitch_ratio``) or the LAST entry of its catalog effect in the vehicle's
    effects (the refinement's, which the file lists after the vehicle's own), added at its neutral values
    where the file has none (a coefficient the refinement left where it was)."""
    from .effects import CATALOG
    from .vehicle import ROTOR_PROPERTIES as PROPERTIES  # (the keys the refinement may write)

    effects = [{"name": e["name"], "parameters": dict(e["parameters"])} for e in vehicle.effects]
    props: dict = {}
    for p, x in zip(params, values):
        eff, name = p["effect"], p["parameter"]
        if eff in PROPERTIES:
            if eff == "rotor_torque_gains":
                props.setdefault(eff, [float(g) for g in vehicle.rotor_torque_gains])[int(name)] = float(x)
            else:
                props[eff] = float(x)
            continue
        for e in (eff, *p.get("shared_with", ())):
            hit = [k for k, f in enumerate(effects) if f["name"] == e]
            if hit:
                effects[hit[-1]]["parameters"][name] = float(x)
            else:
                effects.append({"name": e, "parameters": {**dict(zip(CATALOG[e].params, CATALOG[e].neutral)),
                                                          name: float(x)}})
    return (vehicle.with_changes(**props) if props else vehicle), effects


def current(vehicle, params: list[dict]) -> np.ndarray:
    """The values the vehicle file holds for ``params`` (as :func:`perturbed` sets them; NaN where absent and not
    a neutral coefficient)."""
    from .effects import CATALOG
    from .vehicle import ROTOR_PROPERTIES as PROPERTIES  # (the keys the refinement may write)

    out = []
    for p in params:
        eff, name = p["effect"], p["parameter"]
        if eff in PROPERTIES:
            v = vehicle.rotor_torque_gains[int(name)] if eff == "rotor_torque_gains" else getattr(vehicle, eff)
            out.append(float(v))
            continue
        hit = [f for f in vehicle.effects if f["name"] == eff]
        out.append(float(hit[-1]["parameters"][name]) if hit else
                   float(dict(zip(CATALOG[eff].params, CATALOG[eff].neutral))[name]))
    return np.asarray(out, float)


# the band's scale per quantity (the keys: rollout.QUANTITIES, as the bands file and training.json write it):
# the factor on the radii that makes the 90 % band cover its share on validation data; None: none found
Scale: TypeAlias = "dict[str, float | None]"


# ---- band sources -------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Source:
    """What a model's band is drawn from: ``kind`` ``parameters`` (``params``, their ``written`` values,
    ``covariance`` and ``bounds``) or ``ensemble`` (``members``: :class:`qr.residual.Residual`), and the
    scale per quantity chosen on validation data (``scale``; None: unscaled) with where (``calibrated_on``)."""

    kind: str
    file: str
    scale: Scale | None
    calibrated_on: str
    params: tuple = ()
    written: np.ndarray | None = None
    covariance: np.ndarray | None = None
    bounds: np.ndarray | None = None
    members: tuple = ()
    scale50: Scale | None = None  # the 50 % band's scale (None: ``scale``)

    def plants(self, vehicle, draws: int, seed: int) -> np.ndarray:
        """The plants (1 + draws, n): the vehicle as given, then each draw (each member of an ensemble)."""
        from .sim.plant import true_params

        centre = true_params(vehicle, list(vehicle.effects))
        if self.kind == "ensemble":
            rows = [centre]
            for res in self.members:
                v = vehicle.with_changes()
                v.residual = res
                rows.append(true_params(v, list(v.effects)))
            return np.ascontiguousarray(np.array(rows))
        thetas = draw_parameters(self.written, self.covariance, self.bounds, draws, seed)
        rows = [centre] + [true_params(*perturbed(vehicle, list(self.params), th)) for th in thetas]
        return np.ascontiguousarray(np.array(rows))


def parameter_block(refine_block: dict) -> dict | None:
    """A ``qr.bands/1`` document of kind ``parameters`` from ``diagnosis.json``'s ``refine`` block (None when it
    carries no covariance)."""
    cov = (refine_block or {}).get("parameter_covariance")
    if not cov or not cov.get("parameters"):
        return None
    ps = refine_block["parameters"]
    params = [{"effect": ps[i]["effect"], "parameter": ps[i]["parameter"], "label": ps[i]["label"],
               "shared_with": ps[i].get("shared_with", []), "written": ps[i]["written"],
               "bounds": ps[i]["bounds"]} for i in cov["parameters"]]
    return {"schema": SCHEMA, "kind": "parameters", "parameters": params, "covariance": cov["matrix"],
            "scale": cov.get("band_scale"), "scale50": cov.get("band_scale50"),
            "calibrated_on": cov.get("calibrated_on", "")}


def read_source(doc: dict, file: str, base: Path) -> Source:
    """A :class:`Source` from a ``qr.bands/1`` document (``base``: the folder its member files are relative to)."""
    if doc.get("schema") != SCHEMA or doc.get("kind") not in ("parameters", "ensemble"):
        raise ValueError(f"{file} is not a {SCHEMA} document")
    if doc["kind"] == "ensemble":
        from .residual import absolute, load

        members = tuple(load(absolute(m["residual"], base), Path(base) / "x.yaml") for m in doc["members"])
        return Source("ensemble", file, doc.get("scale"), doc.get("calibrated_on", ""), members=members,
                      scale50=doc.get("scale50"))
    params = tuple(doc["parameters"])
    return Source("parameters", file, doc.get("scale"), doc.get("calibrated_on", ""), params,
                  np.array([p["written"] for p in params], float), np.array(doc["covariance"], float),
                  np.array([p["bounds"] for p in params], float), scale50=doc.get("scale50"))


def source_of(vehicle_file, vehicle) -> tuple[Source | None, str]:
    """The band source of a vehicle file ``X.yaml``: ``X.bands.json`` beside it, else the ``refine`` block of the
    ``diagnosis.json`` beside an ``extended_vehicle.yaml``; where there is none or it does not fit, why."""
    path = Path(str(vehicle_file))
    side = path.with_name(path.stem + SUFFIX)
    doc, file = None, None
    try:
        if side.is_file():
            doc, file = json.loads(side.read_text()), str(side)
        elif path.name == "extended_vehicle.yaml" and (path.parent / "diagnosis.json").is_file():
            diag = json.loads((path.parent / "diagnosis.json").read_text())
            doc, file = parameter_block(diag.get("refine") or {}), str(path.parent / "diagnosis.json")
    except (OSError, ValueError):
        return None, f"its band file {side} cannot be read"
    if doc is None:
        return None, ("no parameter covariance (qr diagnose ... diagnose.refine=rollout) or residual ensemble "
                      "(qr learn residual, learn.members) is known for it")
    try:
        src = read_source(doc, file, path.parent)
    except (ValueError, KeyError, TypeError) as e:
        return None, f"its band file {file} is not usable ({e})"
    if src.kind == "parameters":
        have = current(vehicle, list(src.params))
        if not np.allclose(have, src.written, rtol=1e-9, atol=1e-15):
            return None, f"the parameters of {file} are not the vehicle file's (a file edited since)"
    elif getattr(vehicle, "residual", None) is None:
        return None, f"{file} holds a residual ensemble but the vehicle carries no residual"
    return src, ""


def scale_words(scale: dict | None) -> str:
    if not scale:
        return "unscaled"
    return ", ".join(f"{q} × {scale[q]:.3g}" if scale.get(q) is not None else f"{q} unscaled" for q in QUANTITIES)


# ---- the bands of one evaluation ------------------------------------------------------------------------

class BandSet:
    """The bands of ``qr evaluate``'s models as they are drawn: each model's source and plants, and its
    :class:`Spread` per flight as the flights' pieces are added (:meth:`add`); :meth:`result` freezes them."""

    def __init__(self, keys: list[str], files: list, vehicles: list, draws: int, seed: int, say=lambda m: None):
        self.sources, self.plants, self.missing = {}, {}, {}
        self.draws, self.seed = draws, seed
        for key, file, v in zip(keys, files, vehicles):
            src, why = source_of(file, v)
            if src is None:
                self.missing[key] = why
                continue
            if src.kind == "ensemble" and len(src.members) < 2:
                self.missing[key] = f"{src.file} holds {len(src.members)} member(s); a band needs two or more"
                continue
            self.sources[key] = src
            self.plants[key] = src.plants(v, draws, seed)
            say(f"band of {key}: {_describe(src, draws)}")
        self.spreads: dict = {k: {} for k in self.sources}

    def add(self, flight: str, w: Windows, H: int) -> None:
        for key, Ps in self.plants.items():
            have = self.spreads[key].setdefault(flight, [])
            have.append(spread([w], Ps, H, first_piece=len(have)))

    def result(self) -> Bands:
        return Bands(self.draws, self.seed, dict(self.sources),
                     {k: {f: Spread.join(parts) for f, parts in per.items()} for k, per in self.spreads.items()},
                     dict(self.missing))


def _describe(src: Source, draws: int) -> str:
    what = (f"{len(src.members)} residual members (flights resampled by flight)" if src.kind == "ensemble" else
            f"{draws} draws of {len(src.params)} refined parameters from their covariance")
    return f"{what}, {src.file}; scale {scale_words(src.scale)}"


@dataclass(frozen=True)
class Bands:
    """The bands of one evaluation: per banded model its source and its :class:`Spread` per flight (the
    flight's pieces joined, numbered in order); ``missing``: per model without a band, why."""

    draws: int
    seed: int
    sources: dict[str, Source]
    spreads: dict[str, dict[str, Spread]]
    missing: dict[str, str]

    def spread_of(self, key: str, flight: str) -> Spread:
        return self.spreads[key].get(flight, Spread.join([]))

    def blocks(self, H: int) -> tuple[dict, dict]:
        """``({model: block}, {model: why no band})``: per model its kind, source, scale, draws and the
        coverage at h = H pooled over the flights (``coverage90``, ``coverage50``: the mean over p, v, R, ω;
        ``by_quantity``) and per flight."""
        out = {}
        for key, src in self.sources.items():
            per = {f: coverage(sp, src.scale, src.scale50) for f, sp in self.spreads[key].items()}
            pooled = coverage(Spread.join(list(self.spreads[key].values())), src.scale, src.scale50)
            out[key] = {"kind": src.kind, "source": src.file,
                        "draws": len(src.members) if src.kind == "ensemble" else self.draws,
                        "seed": None if src.kind == "ensemble" else self.seed,
                        "parameters": [p.get("label", p["effect"]) for p in src.params] if src.params else None,
                        "scale": src.scale, "scale50": src.scale50, "calibrated_on": src.calibrated_on, "horizon": H,
                        "levels": list(LEVELS), **pooled,
                        "per_flight": {f: {k: c[k] for k in ("coverage90", "coverage50")} for f, c in per.items()}}
        return out, dict(self.missing)
