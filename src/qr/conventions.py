"""A log's frames, orders, units and rotor numbering, checked from its physics before any identification.

Each check (thrust axis, gyro, rotor layout) compares the log as written with the common mistakes read back
into the spec's convention (docs/spec/flight-log.md), on a relation every flight obeys whatever its effects;
a reading that explains the log far better (``RATIO``; :func:`check_rotor_layout`) is refused in one line
naming it and the fix.  The checks, readings and thresholds: docs/cli.md "Convention checks".
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Callable

import numpy as np
import pandas as pd

from .airborne import airborne_mask
from .errors import QrInputError
from .flight import GYRO, HOVER_RATIO_LIMITS, POSITION, QUATERNION, ROTORS, to_spec_frames
from .frames import G, quat_to_rot
from .identification.edge import Margins, rank_key

CHECKS = ("thrust_axis", "gyro", "rotor_layout")
SMOOTH_S = 0.2  # Savitzky-Golay window shared by every signal (s): mocap second derivatives need it
MIN_ROWS = 200  # airborne samples needed for a check to speak
MAX_ROWS = 60000  # a longer log is checked on evenly spaced stretches of this many samples in all
STRETCH = 2000  # ... each this long
MAX_LAG_S = 0.15  # the rotor stream's stamp may be this far off the motion capture's (s) for the layout check
RATIO = 2.0  # a reading must cut the residual RMS by this factor to be the likely mistake
Z_LAYOUT = 4.0  # standard errors by which another numbering's summed correlation must beat the written one
BLOCK_S = 1.0  # the layout check's jackknife blocks (s): several closed-loop correlation times of the smoothing
MIN_BLOCKS = 10  # blocks the paired standard error needs (a 5-9 s measured flight: the Fisher rule alone)
Z_PAIRED = 3.0  # paired standard errors by which another reading must beat the file's (chosen: the correct
# files' best other reading sits below -1 on every synthetic flight and below +1 on 146 measured ones)
MIN_LAYOUT_GAIN = 0.1  # ... and the least summed-correlation gain it names (chosen: a tenth of one axis's)


@dataclass(frozen=True)
class Reading:
    """One way a log may have been written: ``read`` turns it into the spec's convention."""

    name: str
    mistake: str  # what the log looks like, for the error line
    fix: str
    read: Callable[[pd.DataFrame], pd.DataFrame]


@dataclass(frozen=True)
class CheckResult:
    """What one check measured, and whether the log passes it."""

    name: str
    passed: bool
    measured: str  # one sentence, from the numbers
    mistake: str | None = None
    fix: str | None = None

    def as_dict(self) -> dict:
        return {"check": self.name, "passed": self.passed, "measured": self.measured,
                **({"mistake": self.mistake, "fix": self.fix} if not self.passed else {})}


@dataclass(frozen=True)
class FlightChecks:
    """One flight's convention checks, each with what it measured (``diagnosis.json``'s ``conventions``)."""

    flight: str
    checks: tuple[CheckResult, ...]

    def record(self) -> dict:
        return {"flight": self.flight, "checks": [c.as_dict() for c in self.checks]}


def _with(df: pd.DataFrame, cols: list[str], values) -> pd.DataFrame:
    out = df.copy()
    out[cols] = np.asarray(values, float).reshape(len(df), len(cols))
    return out


def _q(df):
    return df[QUATERNION].to_numpy(float)


# the command a fix names: {log} and {vehicle} are filled in by require() with the user's own files
CONVERT_NED_FRD = "qr ingest {log} --vehicle {vehicle} --frame ned-frd --out FLIGHT.csv"

THRUST_READINGS = (
    Reading("scalar_last", "the quaternion looks scalar-last (x, y, z, w)",
            "write it scalar-first as qw, qx, qy, qz",
            lambda df: _with(df, QUATERNION, _q(df)[:, [3, 0, 1, 2]])),
    Reading("world_to_body", "the quaternion looks like world -> body (the conjugate of the spec's)",
            "give the attitude body -> world: negate qx, qy, qz",
            lambda df: _with(df, QUATERNION, _q(df) * np.array([1.0, -1, -1, -1]))),
    Reading("z_down", "the position looks z down (pz negated)",
            "give positions in a z-up world frame (negate pz, and check the attitude's frame too)",
            lambda df: _with(df, ["pz"], -df["pz"].to_numpy(float))),
    Reading("ned_frd", "the log looks NED world with an FRD body (PX4's frames)",
            f"convert it to the spec's ENU world / FLU body: {CONVERT_NED_FRD} (positions, velocity, attitude, "
            "gyro and accelerometer; docs/ingest.md)",
            lambda df: to_spec_frames(df, "ned-frd")),
    Reading("millimetres", "the positions look like millimetres",
            "divide px, py, pz by 1000 so they are in metres",
            lambda df: _with(df, POSITION, df[POSITION].to_numpy(float) / 1000)),
    Reading("centimetres", "the positions look like centimetres",
            "divide px, py, pz by 100 so they are in metres",
            lambda df: _with(df, POSITION, df[POSITION].to_numpy(float) / 100)),
)

GYRO_READINGS = (
    Reading("gyro_frd", "the gyro looks FRD (y and z negated against the spec's FLU body)",
            "negate gy and gz", lambda df: _with(df, GYRO, df[GYRO].to_numpy(float) * np.array([1.0, -1, -1]))),
    Reading("gyro_degrees", "the gyro looks like degrees per second",
            "multiply gx, gy, gz by pi/180 so they are in rad/s",
            lambda df: _with(df, GYRO, np.radians(df[GYRO].to_numpy(float)))),
)


# ---- signals on a uniform grid, per airborne stretch ---------------------------------------------------

def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.view(np.int8), [0]])))
    return list(zip(edges[::2], edges[1::2]))


def _pieces(df: pd.DataFrame, vehicle) -> list[pd.DataFrame]:
    """The airborne stretches long enough to differentiate, each on a uniform grid (dropouts bridged);
    of a long log, evenly spaced stretches of ``MAX_ROWS`` samples in all (the conventions hold
    throughout a log: a few minutes tell them)."""
    from .segments import gap_threshold

    t = df["t"].to_numpy(float)
    if len(t) < MIN_ROWS:
        return []
    try:
        air = airborne_mask(df, vehicle)
    except Exception:  # a log the airborne detector cannot read: every row
        air = np.ones(len(t), bool)
    step, gap = float(np.median(np.diff(t))), gap_threshold(t)
    out = []
    for a, b in _runs(air):
        rows = df.iloc[a:b]
        tt = rows["t"].to_numpy(float)
        cuts = np.flatnonzero(np.diff(tt) > gap) + 1
        for part in np.split(np.arange(len(tt)), cuts):
            if len(part) * 1.0 < 3 * SMOOTH_S / step + 10:
                continue
            sub = rows.iloc[part]
            ts = sub["t"].to_numpy(float)
            grid = np.arange(ts[0], ts[-1] + 0.5 * step, step)
            cols = {}
            for c in sub.columns:
                y = sub[c].to_numpy(float)
                ok = np.isfinite(y)
                cols[c] = np.interp(grid, ts[ok], y[ok]) if ok.sum() >= 2 else np.full(len(grid), np.nan)
            cols["t"] = grid
            out.append(pd.DataFrame(cols))
    if sum(len(p) for p in out) > MAX_ROWS:
        short = [p.iloc[idx].reset_index(drop=True) for p in out
                 for idx in np.array_split(np.arange(len(p)), max(1, len(p) // STRETCH))]
        keep = np.unique(np.linspace(0, len(short) - 1, MAX_ROWS // STRETCH).round().astype(int))
        out = [short[i] for i in keep]
    return out


def _window(step: float) -> int:
    return max(7, int(round(SMOOTH_S / step)) | 1)


def _smooth(y: np.ndarray, step: float, deriv: int = 0) -> np.ndarray:
    """Savitzky-Golay smoothing or derivative (cubic, ``_window`` samples) along axis 0; NaN within half a
    window of either end, which every check drops.  The local cubic's least-squares row, not
    ``scipy.signal.savgol_filter``: importing scipy.signal (it pulls scipy.stats) cost a third of a second
    of every ``qr diagnose`` (benchmarks/diagnose.py), and the edges are never used here."""
    from math import factorial

    m = _window(step)
    h = m // 2
    x = np.arange(-h, h + 1, dtype=float)
    coeff = np.linalg.pinv(np.vander(x, 4, increasing=True))[deriv] * factorial(deriv) / step**deriv
    y = np.asarray(y, float)
    out = np.full(y.shape, np.nan)
    if len(y) >= m:
        windows = np.lib.stride_tricks.sliding_window_view(y, m, axis=0)  # (N - m + 1, ..., m)
        out[h:len(y) - h] = windows @ coeff
    return out


def _unit(q: np.ndarray) -> np.ndarray:
    return q / np.linalg.norm(q, axis=1, keepdims=True)


# ---- thrust axis -----------------------------------------------------------------------------------------

def _thrust_fit(pieces: list[pd.DataFrame], vehicle) -> "ThrustFit":
    """Least squares of ``f ≈ k (T/m) R e_z + c - R (d ⊙ v_b)`` over ``pieces``: the thrust along body z,
    a constant world force and a linear drag in body axes (every flight has some; fitted, it leaves the
    readings' differences to decide)."""
    F, X, V = [], [], []
    for p in pieces:
        step = float(p["t"].iloc[1] - p["t"].iloc[0])
        pos = p[POSITION].to_numpy(float)
        acc, vel = _smooth(pos, step, 2), _smooth(pos, step, 1)
        f = acc + np.array([0.0, 0.0, G])
        R = quat_to_rot(_unit(p[QUATERNION].to_numpy(float)))
        T, _ = vehicle.rotors.thrust_torque(p[ROTORS].to_numpy(float))
        thrust = _smooth(T, step)[:, None] / vehicle.mass * R[:, :, 2]
        v_b = np.einsum("nji,nj->ni", R, vel)
        drag = R * v_b[:, None, :]  # column j: R e_j v_bj
        n = _window(step) // 2  # the filter's own edges
        F.append(f[n:-n]), X.append(thrust[n:-n]), V.append(drag[n:-n])
    f, x, dv = np.vstack(F), np.vstack(X), np.concatenate(V)
    ok = np.isfinite(f).all(axis=1) & np.isfinite(x).all(axis=1) & np.isfinite(dv).all(axis=(1, 2))
    f, x, dv = f[ok], x[ok], dv[ok]
    A = np.zeros((len(f), 3, 7))
    A[:, :, 0] = x
    A[:, :, 1:4] = np.eye(3)
    A[:, :, 4:7] = -dv
    A = A.reshape(-1, 7)
    sol, *_ = np.linalg.lstsq(A, f.ravel(), rcond=None)
    r = (f.ravel() - A @ sol).reshape(-1, 3)
    return ThrustFit(np.sqrt(np.mean(r**2, axis=0)), float(sol[0]), sol[1:4], len(f))


@dataclass(frozen=True)
class ThrustFit:
    residual: np.ndarray  # RMS of the specific force's residual per world axis (m/s², the reading's length unit)
    gain: float  # k: the rotor thrust's scale (1: the file's C_T and mass balance the flight)
    constant: np.ndarray  # c (m/s²)
    rows: int

    @property
    def plausible(self) -> bool:
        """Thrust along +z at a gain a vehicle file can be off by, no constant force beyond half the weight."""
        lo, hi = HOVER_RATIO_LIMITS
        return lo <= self.gain <= hi and float(np.linalg.norm(self.constant)) < 0.5 * G

    @property
    def relative(self) -> np.ndarray:
        """The residual per axis in units of the thrust's own scale (a reading that rescales lengths
        rescales both)."""
        return self.residual / self.gain / G if self.gain > 0 else np.full(3, np.inf)

    @property
    def total(self) -> float:
        return float(np.sqrt(np.mean(self.relative**2)))

    def beaten_by(self, other: "ThrustFit") -> bool:
        """Does ``other`` explain the specific force ``RATIO`` times better on some axis, and no worse
        on any (a mistake in one axis, as z down, shows on that axis alone)?"""
        mine, theirs = self.relative, other.relative
        return bool(np.all(theirs <= 1.1 * mine) and np.any(theirs * RATIO < mine))


def _explained(fit: ThrustFit) -> str:
    lo, hi = HOVER_RATIO_LIMITS
    if fit.gain <= 0:
        return "points against the rotor thrust"
    if not lo <= fit.gain <= hi:
        return f"needs the rotor thrust x{fit.gain:.3g} to balance it"
    return f"follows the rotor thrust along body z to {100 * float(fit.relative.max()):.2g} % of g"


def check_thrust_axis(pieces: list[pd.DataFrame], vehicle) -> CheckResult:
    if sum(len(p) for p in pieces) < MIN_ROWS:
        return CheckResult("thrust_axis", True, "too few airborne samples to check the frames")
    fit0 = _thrust_fit(pieces, vehicle)
    alt = []
    for reading in THRUST_READINGS:
        fit = _thrust_fit([reading.read(p) for p in pieces], vehicle)
        if fit.plausible:
            alt.append((fit, reading))
    measured = f"as written, the specific force the positions give {_explained(fit0)}"
    if alt:
        fit, best = min(alt, key=lambda a: a[0].total)
        if not fit0.plausible or fit0.beaten_by(fit):
            return CheckResult("thrust_axis", False, f"{measured}; read so, it {_explained(fit)}",
                               best.mistake, best.fix)
    # as written implausible, and no reading better: no convention explains the log (a synthetic table, a
    # tether); not refused here: the diagnosis says when the model does not describe a flight
    return CheckResult("thrust_axis", True, measured + ("" if fit0.plausible else "; no other reading explains it"))


# ---- gyro -------------------------------------------------------------------------------------------------

def _attitude_rates(p: pd.DataFrame, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Body rate and its derivative (N, 3) the attitude implies: ``ω = 2 vec(q⁻¹ ⊗ q̇)``."""
    from .frames import quat_multiply

    q = _unit(p[QUATERNION].to_numpy(float))
    qd = _smooth(q, step, 1)
    qs = _smooth(q, step)
    w = 2 * quat_multiply(qs * np.array([1.0, -1, -1, -1]), qd)[:, 1:] / np.sum(qs**2, axis=1, keepdims=True)
    return w, _smooth(w, step, 1)


def _gyro_fit(pieces: list[pd.DataFrame]) -> tuple[float, float]:
    """(residual RMS of gyro ≈ ω + bias, RMS of ω's variation) over ``pieces`` (rad/s)."""
    W, Gy = [], []
    for p in pieces:
        step = float(p["t"].iloc[1] - p["t"].iloc[0])
        w, _ = _attitude_rates(p, step)
        n = _window(step) // 2
        W.append(w[n:-n]), Gy.append(_smooth(p[GYRO].to_numpy(float), step)[n:-n])
    w, g = np.vstack(W), np.vstack(Gy)
    ok = np.isfinite(w).all(axis=1) & np.isfinite(g).all(axis=1)
    w, g = w[ok], g[ok]
    r = (g - g.mean(axis=0)) - (w - w.mean(axis=0))
    return float(np.sqrt(np.mean(r**2))), float(np.sqrt(np.mean((w - w.mean(axis=0)) ** 2)))


def check_gyro(pieces: list[pd.DataFrame], vehicle) -> CheckResult:
    if not pieces or not all(c in pieces[0] for c in GYRO):
        return CheckResult("gyro", True, "no gyro logged")
    pieces = [p for p in pieces if np.isfinite(p[GYRO].to_numpy(float)).all()]
    if sum(len(p) for p in pieces) < MIN_ROWS:
        return CheckResult("gyro", True, "too few airborne samples with a gyro to check it")
    r0, spread = _gyro_fit(pieces)
    measured = (f"the gyro follows the attitude's rate with a residual of {r0:.3g} rad/s "
                f"(the rate varies by {spread:.3g} rad/s)")
    alt = []
    for reading in GYRO_READINGS:
        r, _ = _gyro_fit([reading.read(p) for p in pieces])
        alt.append((r, reading))
    r, best = min(alt, key=lambda a: a[0])
    if r * RATIO < r0:
        return CheckResult("gyro", False, f"{measured}; read as {best.name.replace('_', ' ')}, {r:.3g} rad/s",
                           best.mistake, best.fix)
    return CheckResult("gyro", True, measured)


# ---- rotor layout -----------------------------------------------------------------------------------------

def _torque_pairs(pieces: list[pd.DataFrame], vehicle) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per piece: u² per rotor (N, n), the torque the attitude needs (N, 3), and per torque axis the
    torques a rotor map leaves out (N, 3, 4): a constant, the body rate's damping, the cross-axis body
    velocity's blade flapping, the thrust's CG-offset lever; all smoothed alike."""
    out = []
    J = np.asarray(vehicle.inertia, float)
    for p in pieces:
        step = float(p["t"].iloc[1] - p["t"].iloc[0])
        w, wd = _attitude_rates(p, step)
        need = wd * J + np.cross(w, w * J)
        u2 = _smooth(p[ROTORS].to_numpy(float) ** 2, step)
        R = quat_to_rot(_unit(p[QUATERNION].to_numpy(float)))
        v_b = np.einsum("nji,nj->ni", R, _smooth(p[POSITION].to_numpy(float), step, 1))
        T = u2.sum(axis=1)
        one = np.ones(len(T))
        z = np.stack([np.column_stack([one, w[:, 0], v_b[:, 1], T]), np.column_stack([one, w[:, 1], v_b[:, 0], T]),
                      np.column_stack([one, w[:, 2], one * 0, one * 0])], axis=1)
        n = _window(step) // 2
        u2, need, z = u2[n:-n], need[n:-n], z[n:-n]
        ok = np.isfinite(u2).all(axis=1) & np.isfinite(need).all(axis=1) & np.isfinite(z).all(axis=(1, 2))
        out.append((u2[ok], need[ok], z[ok]))
    return out


def _partial(pairs, lag: int, step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """With the rotor stream ``lag`` samples late: per torque axis, u² (N, n) and the needed torque (N,), each
    with the left-out torques (``_torque_pairs``) projected out: what a rotor numbering must explain; and
    each row's block (``BLOCK_S`` of its piece's needed-torque rows: the same id at every lag)."""
    U, N, Z, B = [], [], [], []
    for i, (u2, need, z) in enumerate(pairs):
        m = len(u2) - abs(lag)
        if m > 0:
            a, b = max(lag, 0), max(-lag, 0)
            U.append(u2[a:a + m]), N.append(need[b:b + m]), Z.append(z[b:b + m])
            B.append(i * 10**9 + (np.arange(b, b + m) * step // BLOCK_S).astype(np.int64))
    u2, need, z = np.vstack(U), np.vstack(N), np.concatenate(Z)
    us, ns = [], []
    for k in range(3):
        Q = np.linalg.qr(z[:, k][:, np.any(z[:, k] != 0, axis=0)])[0]
        us.append(u2 - Q @ (Q.T @ u2))
        ns.append(need[:, k] - Q @ (Q.T @ need[:, k]))
    return np.stack(us), np.stack(ns), np.concatenate(B)  # (3, N, n), (3, N), (N,)


@dataclass(frozen=True)
class LayoutStats:
    """Per block of ``_partial``'s rows: the small Gram matrices a rotor map's partial correlation is made of
    (a map's torque is linear in u²): ``C`` (K, 3, n, n) of u², ``d`` (K, 3, n) of u² with the needed
    torque, ``e`` (K, 3) of the needed torque; ``ids`` (K,) the blocks."""

    C: np.ndarray
    d: np.ndarray
    e: np.ndarray
    ids: np.ndarray

    @classmethod
    def of(cls, us: np.ndarray, ns: np.ndarray, blocks: np.ndarray) -> "LayoutStats":
        starts = np.flatnonzero(np.r_[True, blocks[1:] != blocks[:-1]])  # blocks are runs of rows
        C = np.add.reduceat(np.einsum("knr,kns->nkrs", us, us), starts, axis=0)
        d = np.add.reduceat(np.einsum("knr,kn->nkr", us, ns), starts, axis=0)
        e = np.add.reduceat(np.einsum("kn,kn->nk", ns, ns), starts, axis=0)
        return cls(C, d, e, blocks[starts])

    def on(self, ids: np.ndarray) -> "LayoutStats":
        """The same blocks as ``ids`` (zeros where this lag has none of a block's rows)."""
        at = np.searchsorted(ids, self.ids)
        out = [np.zeros((len(ids),) + a.shape[1:]) for a in (self.C, self.d, self.e)]
        for o, a in zip(out, (self.C, self.d, self.e)):
            o[at] = a
        return LayoutStats(*out, ids)


def _correlations(C: np.ndarray, d: np.ndarray, e: np.ndarray, maps: np.ndarray) -> np.ndarray:
    """Partial correlation (c, 3) of each torque axis of each rotor map ``maps`` (c, 4, n) with the needed
    torque, from the axes' Gram matrices ``C`` (3, n, n), ``d`` (3, n), ``e`` (3,)."""
    b = maps[:, 1:, :]  # (c, 3, n)
    num = np.einsum("ckr,kr->ck", b, d)
    den = np.sqrt(np.einsum("ckr,krs,cks->ck", b, C, b) * e)
    return np.divide(num, den, out=np.zeros_like(num), where=den > 0)


@dataclass(frozen=True)
class LayoutReading:
    """A rotor map the log may have been written for: ``geometry`` (``"file"``: the vehicle file's rotors;
    ``"plus"``, ``"x"``: the standard layouts at the file's arm length), the log's column ``j`` driving the
    geometry's rotor ``order[j]``, the yaw signs times ``yaw``."""

    geometry: str
    order: tuple[int, ...]
    yaw: float

    def rotors_said(self) -> str:
        """``u1, u4, u3, u2``: the log's columns that are the geometry's rotors 1..n."""
        inv = np.argsort(self.order)
        return ", ".join(ROTORS[j] for j in inv)

    def said(self, n: int) -> str:
        same = self.order == tuple(range(n))
        what = "the file's layout" if self.geometry == "file" else f"layout {self.geometry}"
        if not same:
            what += f" with its rotors 1..{n} in the log's {self.rotors_said()}"
        return what + ("" if self.yaw > 0 else (" and" if not same else " with") + " the yaw signs reversed")


def _standard(vehicle, geometry: str) -> np.ndarray:
    """The rotor map of the standard layout ``geometry`` at the file's arm length, C_T and C_Q."""
    from .rotors import PLUS_YAW_SIGNS, plus_positions, x_positions

    r = vehicle.rotors
    pos = {"plus": plus_positions, "x": x_positions}[geometry](float(np.max(np.hypot(*r.positions.T))))
    return np.vstack([r.thrust_coeff * np.ones(4), r.thrust_coeff * pos[:, 1], -r.thrust_coeff * pos[:, 0],
                      r.torque_coeff * np.array(PLUS_YAW_SIGNS)])


def layout_readings(vehicle) -> tuple[list[LayoutReading], np.ndarray]:
    """The vehicle file's rotor map first, then every other numbering and yaw convention of it and of the
    standard layouts (plus, x) with four rotors, each distinct map once (the file's own reading kept)."""
    B = vehicle.rotors.matrix
    n = B.shape[1]
    geometries = [("file", B)] + ([(g, _standard(vehicle, g)) for g in ("plus", "x")] if n == 4 else [])
    readings, maps = [], []
    scale = np.abs(B).max(axis=1, keepdims=True)
    for g, M in geometries:
        for order in itertools.permutations(range(n)):
            for yaw in (1.0, -1.0):
                m = M[:, list(order)] * np.array([1.0, 1.0, 1.0, yaw])[:, None]
                if any(np.all(np.abs(m - q) <= 1e-6 * scale) for q in maps):
                    continue
                readings.append(LayoutReading(g, order, yaw)), maps.append(m)
    return readings, np.stack(maps)


def _jackknife_difference(a: LayoutStats, b: LayoutStats, map_a: np.ndarray, map_b: np.ndarray) -> float:
    """Standard error (delete-one-block jackknife) of map ``b``'s summed correlation minus map ``a``'s, each
    on its own lag's statistics over the same blocks: paired, as both read the same needed torque."""
    ids = np.union1d(a.ids, b.ids)
    a, b = a.on(ids), b.on(ids)
    K = len(ids)
    diff = np.empty(K)
    tot_a, tot_b = (a.C.sum(0), a.d.sum(0), a.e.sum(0)), (b.C.sum(0), b.d.sum(0), b.e.sum(0))
    for k in range(K):
        ra = _correlations(tot_a[0] - a.C[k], tot_a[1] - a.d[k], tot_a[2] - a.e[k], map_a[None])[0].sum()
        rb = _correlations(tot_b[0] - b.C[k], tot_b[1] - b.d[k], tot_b[2] - b.e[k], map_b[None])[0].sum()
        diff[k] = rb - ra
    return float(np.sqrt((K - 1) / K * np.sum((diff - diff.mean()) ** 2)))


def _fix(reading: LayoutReading, vehicle, maps_row: np.ndarray) -> str:
    """How to write the vehicle file (or the log) so that its rotor map is ``reading``'s."""
    n = vehicle.rotors.n
    if reading.geometry == "file":
        if reading.order == tuple(range(n)):
            return "flip every yaw_sign in the vehicle file's layout"
        return "reorder u1..u4 to the vehicle file's rotor numbering (or fix the layout in the vehicle file)"
    if reading.order == tuple(range(n)) and reading.yaw > 0:
        return f"write layout: {reading.geometry} in the vehicle file"
    ct, cq = vehicle.rotors.thrust_coeff, vehicle.rotors.torque_coeff
    rotors = ", ".join(f"{{x: {-maps_row[2, j] / ct:.4g}, y: {maps_row[1, j] / ct:.4g}, "
                       f"yaw_sign: {int(np.sign(maps_row[3, j] / cq))}}}" for j in range(n))
    return f"write the layout as the log's rotors u1..u{n} in order: layout: [{rotors}]"


def check_rotor_layout(pieces: list[pd.DataFrame], vehicle) -> CheckResult:
    """Every numbering of the file's rotors and of the standard layouts (plus, x), both yaw conventions,
    each at its best lag of the rotor stream within ``MAX_LAG_S`` (a stamp offset is a clock's error, qr
    ingest estimates it, not a numbering); the correlation is partial: in closed loop the rotors cancel
    aerodynamic torques (flapping, damping), which can hide the numbering's own correlation (a flapping
    RotorPy flight: roll -0.25 without them).

    Another reading explains the torques clearly better when its summed correlation beats the file's by
    ``Z_LAYOUT`` standard errors of two independent correlations (Fisher, a window's samples one), or, on
    ``MIN_BLOCKS`` blocks or more, by ``Z_PAIRED`` of the paired difference's own (a block jackknife: both
    read the same torque, so their difference varies far less than either) and ``MIN_LAYOUT_GAIN``.
    A plus frame read as x loses about 30 % of each roll and pitch correlation (cos 45°): 0.25-0.4 in all
    on the synthetic flights, 4-9 paired standard errors, within the Fisher rule's 0.42.  The reading must
    explain roll and pitch both (each correlation 2 standard errors above zero)."""
    if sum(len(p) for p in pieces) < MIN_ROWS:
        return CheckResult("rotor_layout", True, "too few airborne samples to check the rotor layout")
    pairs = _torque_pairs(pieces, vehicle)
    step = float(pieces[0]["t"].iloc[1] - pieces[0]["t"].iloc[0])
    rows = sum(len(u) for u, _, _ in pairs)
    se = 1 / np.sqrt(max(rows / _window(step) - 3, 1.0))  # Fisher: a window's samples are one
    reach = int(round(MAX_LAG_S / step))
    readings, maps = layout_readings(vehicle)
    best, stats_of, lag_of = _best_lags(pairs, step, reach, maps)
    written = best[0]
    # the best other reading, ties within numerical noise to the earlier (the same on every machine)
    i = min(range(1, len(readings)), key=lambda j: (-rank_key(float(best[j].sum())), j))
    other, c = readings[i], best[i]
    diff = float(c.sum() - written.sum())
    blocks = len(np.union1d(stats_of[lag_of[0]].ids, stats_of[lag_of[i]].ids))
    paired = _jackknife_difference(stats_of[lag_of[0]], stats_of[lag_of[i]], maps[0], maps[i]) \
        if blocks >= MIN_BLOCKS else float("nan")
    fmt = lambda x: ", ".join(f"{v:.2f}" for v in x)  # noqa: E731
    n = vehicle.rotors.n
    measured = (f"the rotor torque's partial correlation with the torque the attitude needs is {fmt(written)} in "
                f"roll, pitch, yaw (s.e. {se:.2f}) with the file's layout; the best other reading, "
                f"{other.said(n)}, gives {fmt(c)} (summed {diff:+.2f}"
                + (f", paired s.e. {paired:.2f}" if paired == paired else "") + ")")
    m = Margins()
    beaten = m.at_least(diff, Z_LAYOUT * se * np.sqrt(3), on_edge=False) or (
        paired == paired and m.at_least(diff, max(Z_PAIRED * paired, MIN_LAYOUT_GAIN), on_edge=False))
    # a rotor map drives roll and pitch alike: a reading that explains one of them only is no layout (a log
    # whose rotor-1 speed reads 0 half the time: the brushed jana33, roll 0.71, pitch 0.03)
    beaten = beaten and all(m.at_least(float(x), 2 * se, on_edge=False) for x in c[:2])
    if not beaten:
        return CheckResult("rotor_layout", True, measured + ": the file's layout fits")
    return CheckResult("rotor_layout", False, measured + ": that reading fits clearly better",
                       _layout_mistake(other, vehicle), _fix(other, vehicle, maps[i]))


def _best_lags(pairs, step: float, reach: int, maps: np.ndarray):
    """Per reading (row of ``maps``), its partial correlations at its best lag of the rotor stream (the largest
    sum; the earlier lag on a tie), with each lag's statistics and the lag chosen per reading."""
    best, stats_of, lag_of = None, {}, None
    for lag in range(-reach, reach + 1, max(1, reach // 6)):
        st = LayoutStats.of(*_partial(pairs, lag, step))
        stats_of[lag] = st
        c = _correlations(st.C.sum(0), st.d.sum(0), st.e.sum(0), maps)
        if best is None:
            best, lag_of = c, np.full(len(c), lag)
        else:
            better = c.sum(axis=1) > best.sum(axis=1)
            best, lag_of = np.where(better[:, None], c, best), np.where(better, lag, lag_of)
    return best, stats_of, lag_of


def _layout_mistake(other: LayoutReading, vehicle) -> str:
    """The likely mistake, in words, when ``other`` reads the rotor torques clearly better than the file."""
    n = vehicle.rotors.n
    if other.geometry == "file" and other.order == tuple(range(n)):
        return "the rotors' yaw signs look reversed (each rotor spins the other way than the layout says)"
    if other.geometry == "file":
        return f"the rotor columns look numbered differently: the layout's rotors 1..{n} are the log's " \
               f"{other.rotors_said()}" + ("" if other.yaw > 0 else ", with the yaw signs reversed")
    written_said = vehicle.raw.get("layout") if isinstance(vehicle.raw.get("layout"), str) else "its listed rotors"
    return f"the rotor torques look like {other.said(n)}, not the vehicle file's layout ({written_said})"


RUNNERS = {"thrust_axis": check_thrust_axis, "gyro": check_gyro, "rotor_layout": check_rotor_layout}


def check(df: pd.DataFrame, vehicle, skip=()) -> list[CheckResult]:
    """Every convention check not in ``skip``, in ``CHECKS`` order."""
    unknown = [str(x) for x in skip if x not in CHECKS]
    if unknown:
        raise QrInputError("skip_checks", f"unknown convention check '{unknown[0]}'", f"use one of {', '.join(CHECKS)}")
    todo = [name for name in CHECKS if name not in skip]
    pieces = _pieces(df, vehicle) if todo else []
    return [RUNNERS[name](pieces, vehicle) for name in todo]


def require(df: pd.DataFrame, vehicle, path, skip=(), how_to_skip: str = "diagnose.skip_checks=[{name}]",
            vehicle_file=None) -> list[CheckResult]:
    """``check``, refusing the log (one line: the likely mistake and its fix) at the first failure;
    ``how_to_skip``: the setting that turns a check off, as the user writes it (``{name}``: the check);
    ``vehicle_file``: the user's vehicle file, named in a fix that is a command."""
    results = check(df, vehicle, skip)
    for r in results:
        if not r.passed:
            fix = r.fix.replace("{log}", str(path)).replace("{vehicle}", str(vehicle_file or "VEHICLE.yaml"))
            raise QrInputError(path, f"{r.mistake} ({r.measured})",
                               f"{fix}; or, if the log is right, skip this check with "
                               + how_to_skip.format(name=r.name))
    return results
