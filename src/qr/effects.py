"""The effect catalog of ``docs/spec/diagnosis.md``: one entry per effect.

Every catalog term is linear in its parameters (gains through ``gain - 1``), so
each effect is defined by its *design*: an array ``(N, 6, n_params)`` whose
column ``j`` is the term added to ``[f_a; tau_a]`` (body frame) per unit of
parameter ``j``.  ``term`` is the design times the parameters minus their
neutral values.  The same design serves the diagnosis (regressors), the
extended model (prediction) and the tests (expected residual of a hidden effect).
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .allowed import is_number
from .errors import QrInputError
from .frames import GRAVITY, skew
from .rotors import HOVER_RATIO_LIMITS, SPEED_UNIT_NAMES


def _as_slice(idx):
    """``idx`` as a slice where it is a run of consecutive indices (else unchanged)."""
    if isinstance(idx, np.ndarray) and idx.ndim == 1 and idx.dtype.kind in "iu" and idx.size \
            and idx[-1] - idx[0] == idx.size - 1 and np.all(np.diff(idx) == 1):
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


@dataclass
class Signals:
    """Body-frame kinematics and rotor speeds of the tracked point, one row per sample."""

    R: np.ndarray  # (N, 3, 3) body -> world
    v_b: np.ndarray  # (N, 3)
    a_b: np.ndarray  # (N, 3)
    omega: np.ndarray  # (N, 3)
    alpha: np.ndarray  # (N, 3)
    u: np.ndarray  # (N, 4) rotor speeds (vehicle unit)
    u_dot: np.ndarray  # (N, 4)
    p: np.ndarray  # (N, 3) tracked point, world
    # Optional squared rotor speeds smoothed like the position (force rows) and the attitude
    # (torque rows) estimates, and their rates: labels and designs built from them compare like
    # with like (see qr.estimation.matched).  None: use u² and 2 u u̇.
    u2f: np.ndarray | None = None
    u2f_dot: np.ndarray | None = None
    u2t: np.ndarray | None = None
    u2t_dot: np.ndarray | None = None
    # Optional (N, 6) design column of actuator_delay per second of delay, from the exact delayed
    # rotor map (qr.identification.delay); None: the first-order term.
    delay_column: np.ndarray | None = None

    def __len__(self):
        return len(self.u)

    def take(self, idx) -> "Signals":
        """Rows ``idx`` (a slice or indices). A slice, or a run of consecutive indices (most chunks of a
        training part), gives read-only views: no copy of a long flight's signals per chunk."""
        idx = _as_slice(idx)
        view = isinstance(idx, slice)

        def rows(a):
            if a is None:
                return None
            out = a[idx]
            if view:
                out.flags.writeable = False
            return out

        return Signals(*(rows(getattr(self, f)) for f in self.__dataclass_fields__))

    @staticmethod
    def concat(parts: list["Signals"]) -> "Signals":
        """Rows of ``parts`` one after the other (an optional signal only if every part has it)."""
        def cat(f):
            vals = [getattr(p, f) for p in parts]
            return None if any(v is None for v in vals) else np.concatenate(vals)
        return Signals(*(cat(f) for f in Signals.__dataclass_fields__))

    @property
    def u2_force(self) -> np.ndarray:
        return self.u**2 if self.u2f is None else self.u2f

    @property
    def u2_torque(self) -> np.ndarray:
        return self.u**2 if self.u2t is None else self.u2t

    @property
    def u2_force_rate(self) -> np.ndarray:
        return 2 * self.u * self.u_dot if self.u2f_dot is None else self.u2f_dot

    @property
    def u2_torque_rate(self) -> np.ndarray:
        return 2 * self.u * self.u_dot if self.u2t_dot is None else self.u2t_dot


@dataclass(frozen=True)
class Effect:
    name: str
    params: tuple[str, ...]
    units: tuple[str, ...]
    neutral: tuple[float, ...]  # parameter values that mean "no effect"
    design: Callable  # (Signals, Vehicle) -> (N, 6, n_params)
    axes: tuple[int, ...]  # rows of [f_a; tau_a] the term can touch
    first_order: bool = False  # the term is a first-order approximation of the physics
    doc: str = ""
    meaning: str = ""  # what it is, in a reader's words (reports name an effect by it)

    def term(self, params: dict, s: Signals, vehicle) -> np.ndarray:
        """``(N, 6)`` force and torque added to ``[f_a; tau_a]``."""
        theta = np.array([float(params.get(p, n)) - n for p, n in zip(self.params, self.neutral)])
        return self.design(s, vehicle) @ theta


def _zeros(s, k):
    return np.zeros((len(s), 6, k))


def wrench(s, vehicle):
    """Nominal thrust (from the force-row rotor signal) and torques (from the torque-row one)."""
    B = vehicle.rotors.matrix
    return s.u2_force @ B[0], s.u2_torque @ B[1:].T


_wrench = wrench


def _linear_drag(s, v):
    D = _zeros(s, 3)
    for j in range(3):
        D[:, j, j] = -s.v_b[:, j]
    return D


def _quadratic_drag(s, v):
    D = _zeros(s, 3)
    for j in range(3):
        D[:, j, j] = -np.abs(s.v_b[:, j]) * s.v_b[:, j]
    return D


def _rotor_drag(s, v):
    D = _zeros(s, 1)
    omega_sum = np.sqrt(np.maximum(s.u2_force, 0.0)).sum(axis=1)
    D[:, 0, 0] = -omega_sum * s.v_b[:, 0]
    D[:, 1, 0] = -omega_sum * s.v_b[:, 1]
    return D


def _wind_force(s, v):
    D = _zeros(s, 3)
    D[:, 0:3, :] = np.transpose(s.R, (0, 2, 1))  # column j: R^T e_j
    return D


def _bias(rows: slice):
    """A constant on the wrench rows ``rows`` (force 0:3, torque 3:6)."""
    def design(s, v):
        D = _zeros(s, 3)
        D[:, rows, :] = np.eye(3)
        return D
    return design


def _thrust_gain(s, v):
    T, G = _wrench(s, v)
    D = _zeros(s, 1)
    D[:, 2, 0] = T
    D[:, 3, 0] = G[:, 0]
    D[:, 4, 0] = G[:, 1]
    return D


def _mass_error(s, v):
    D = _zeros(s, 1)
    g_b = np.einsum("nji,j->ni", s.R, GRAVITY)
    D[:, 0:3, 0] = -(s.a_b - g_b)
    return D


def height(s, vehicle) -> np.ndarray:
    return s.p[:, 2] - vehicle.ground_z


def _ground_effect(s, v):
    T, _ = _wrench(s, v)
    D = _zeros(s, 1)
    D[:, 2, 0] = T / height(s, v) ** 2
    return D


def _motor_imbalance(s, v):
    B = v.rotors.matrix  # rows T, Γx, Γy, Γz per u²
    uf, ut = s.u2_force, s.u2_torque
    # a rotor's drag torque scales with its thrust relative to the others' (1 + d_i - mean(d)): the common
    # mode stays thrust only, so an all-equal imbalance is thrust_gain in every row (spec)
    yaw = B[3] * ut[:, :4]
    D = _zeros(s, 4)
    for i in range(4):
        D[:, 2, i] = B[0, i] * uf[:, i]
        D[:, 3, i] = B[1, i] * ut[:, i]
        D[:, 4, i] = B[2, i] * ut[:, i]
        D[:, 5, i] = yaw[:, i] - yaw.mean(axis=1)
    return D


def _cg_offset(s, v):
    T = s.u2_torque @ v.rotors.matrix[0]  # a torque row: the attitude-matched signal
    D = _zeros(s, 2)
    D[:, 4, 0] = T  # rx: torque [0, rx T, 0]
    D[:, 3, 1] = -T  # ry: torque [-ry T, 0, 0]
    return D


def _yaw_torque_gain(s, v):
    _, G = _wrench(s, v)
    D = _zeros(s, 1)
    D[:, 5, 0] = G[:, 2]
    return D


def _inertia_error(s, v):
    w, a = s.omega, s.alpha
    D = _zeros(s, 3)
    # -diag(dJ) alpha + (diag(dJ) omega) x omega, one column per dJ entry
    D[:, 3:6, 0] = np.stack([-a[:, 0], -w[:, 0] * w[:, 2], w[:, 0] * w[:, 1]], -1)
    D[:, 3:6, 1] = np.stack([w[:, 1] * w[:, 2], -a[:, 1], -w[:, 0] * w[:, 1]], -1)
    D[:, 3:6, 2] = np.stack([-w[:, 1] * w[:, 2], w[:, 0] * w[:, 2], -a[:, 2]], -1)
    return D


def _actuator_delay(s, v):
    if s.delay_column is not None:
        return s.delay_column[:, :, None].copy()
    # d/dt of the wrench B u² is B d(u²)/dt
    B = v.rotors.matrix
    D = _zeros(s, 1)
    D[:, 2, 0] = -(s.u2_force_rate @ B[0])
    D[:, 3:6, 0] = -(s.u2_torque_rate @ B[1:].T)
    return D


def _marker_offset(s, v):
    A = skew(s.alpha) + skew(s.omega) @ skew(s.omega)  # α×r + ω×(ω×r) = A r
    D = _zeros(s, 3)
    D[:, 0:3, :] = v.mass * A
    return D


def _blade_flapping(s, v):
    D = _zeros(s, 1)
    D[:, 3, 0] = s.v_b[:, 1]
    D[:, 4, 0] = -s.v_b[:, 0]
    return D


def hub_positions(vehicle) -> np.ndarray:
    """(n, 3) m: each rotor hub from the CG, the layout's x, y and the vehicle file's ``hub_z``."""
    pos = vehicle.rotors.positions
    return np.column_stack([pos, np.full(len(pos), vehicle.hub_z)])


def hub_airspeeds(s, vehicle) -> np.ndarray:
    """(N, n, 3): each hub's airspeed ``v_b + ω × r_i`` (body frame)."""
    r = hub_positions(vehicle)
    return s.v_b[:, None, :] + np.cross(s.omega[:, None, :], r[None, :, :])


def _rotor_drag_moment(s, v):
    # the moment about the CG of each hub's H-force -u_i [w_ix, w_iy, 0], per unit k
    r = hub_positions(v)
    w = hub_airspeeds(s, v)
    u = np.sqrt(np.maximum(s.u2_torque, 0.0))  # the torque rows' (attitude-matched) rotor signal
    H = np.zeros_like(w)
    H[..., 0] = -u * w[..., 0]
    H[..., 1] = -u * w[..., 1]
    D = _zeros(s, 1)
    D[:, 3:6, 0] = np.cross(r[None, :, :], H).sum(axis=1)
    return D


def _translational_lift(s, v):
    # each rotor's extra thrust w_ix² + w_iy² per unit k, at its hub (force along body z, r_i × that)
    r = hub_positions(v)
    w = hub_airspeeds(s, v)
    extra = w[..., 0] ** 2 + w[..., 1] ** 2  # (N, n)
    D = _zeros(s, 1)
    D[:, 2, 0] = extra.sum(axis=1)
    D[:, 3, 0] = extra @ r[:, 1]
    D[:, 4, 0] = -(extra @ r[:, 0])
    return D


F, TQ, ALL = (0, 1, 2), (3, 4, 5), (0, 1, 2, 3, 4, 5)
CATALOG: dict[str, Effect] = {e.name: e for e in [
    Effect("linear_drag", ("kx", "ky", "kz"), ("N s/m",) * 3, (0, 0, 0), _linear_drag, F,
           doc="force -diag(k) v_b",
           meaning="air drag proportional to the body velocity"),
    Effect("quadratic_drag", ("cx", "cy", "cz"), ("N s^2/m^2",) * 3, (0, 0, 0), _quadratic_drag, F,
           doc="force -c ⊙ |v_b| ⊙ v_b",
           meaning="air drag growing with the square of the body velocity"),
    Effect("rotor_drag", ("k",), ("N s/m per rotor-speed unit",), (0,), _rotor_drag, (0, 1),
           doc="force -k Ω [v_bx, v_by, 0], Ω = Σ u_i",
           meaning="a horizontal force growing with the rotor speeds and the body velocity (the rotors' drag)"),
    Effect("wind_force", ("fx", "fy", "fz"), ("N",) * 3, (0, 0, 0), _wind_force, F,
           doc="force R^T [fx, fy, fz] (constant in the world frame)",
           meaning="a constant force in the world frame (wind, or a tilted motion-capture vertical)"),
    Effect("body_force_bias", ("bx", "by", "bz"), ("N",) * 3, (0, 0, 0), _bias(slice(0, 3)), F,
           doc="force [bx, by, bz] (constant in the body frame)",
           meaning="a constant force in the body frame (along z: a thrust offset)"),
    Effect("thrust_gain", ("gain",), ("-",), (1,), _thrust_gain, (2, 3, 4),
           doc="force (gain-1)[0,0,T], torque (gain-1)[Γx,Γy,0]",
           meaning="every rotor's thrust scaled: the thrust coefficient C_T times this gain (1: as the file)"),
    Effect("mass_error", ("dm",), ("kg",), (0,), _mass_error, F,
           doc="force -dm (a_b - R^T g)",
           meaning="the mass off by dm (the true mass is m + dm)"),
    Effect("ground_effect", ("k",), ("m^2",), (0,), _ground_effect, (2,),
           doc="force k T / p_z^2 [0, 0, 1]",
           meaning="extra thrust near the floor (k T / height²)"),
    Effect("motor_imbalance", ("d1", "d2", "d3", "d4"), ("-",) * 4, (0, 0, 0, 0), _motor_imbalance, (2, 3, 4, 5),
           doc="rotor i thrust C_T (1 + d_i) u_i^2, drag torque C_Q (1 + d_i - mean(d)) u_i^2",
           meaning="one rotor's thrust and drag torque off by the share d_i against the others (a weak or "
                   "damaged rotor, a speed or command scale: its drag torque scales with its thrust; the rotors' "
                   "yaw-sign pattern of the d_i is read from the yaw torque on that premise)"),
    Effect("cg_offset", ("rx", "ry"), ("m", "m"), (0, 0), _cg_offset, (3, 4),
           doc="torque [-ry T, rx T, 0]",
           meaning="the centre of gravity off the rotor centre: the thrust rolls and pitches the body"),
    Effect("torque_bias", ("tx", "ty", "tz"), ("N m",) * 3, (0, 0, 0), _bias(slice(3, 6)), TQ,
           doc="torque [tx, ty, tz]",
           meaning="a constant torque on the body"),
    Effect("yaw_torque_gain", ("gain",), ("-",), (1,), _yaw_torque_gain, (5,),
           doc="torque (gain-1)[0,0,Γz]",
           meaning="the yaw torque (C_Q / Jzz) times this gain (1: as in the vehicle file)"),
    Effect("inertia_error", ("dJxx", "dJyy", "dJzz"), ("kg m^2",) * 3, (0, 0, 0), _inertia_error, TQ,
           doc="torque -diag(dJ) α + (diag(dJ) ω) × ω",
           meaning="the inertia off by dJ"),
    Effect("actuator_delay", ("delay_s",), ("s",), (0,), _actuator_delay, ALL, first_order=True,
           doc="force and torque -delay d/dt [T-force, Γ] (first order)",
           meaning="the rotors respond late by this delay"),
    Effect("marker_offset", ("rx", "ry", "rz"), ("m",) * 3, (0, 0, 0), _marker_offset, F,
           doc="force m (α × r + ω × (ω × r))",
           meaning="the motion-capture marker off the centre of gravity"),
    Effect("blade_flapping", ("k",), ("N m s/m",), (0,), _blade_flapping, (3, 4),
           doc="torque k [v_by, -v_bx, 0]",
           meaning="the rotor disks tilt against the airflow: a roll/pitch moment growing with the body velocity"),
    Effect("rotor_drag_moment", ("k",), ("N s/m per rotor-speed unit",), (0,), _rotor_drag_moment, TQ,
           doc="torque Σ r_i × (-k u_i [w_ix, w_iy, 0]), w_i = v_b + ω × r_i (hub airspeed)",
           meaning="the moment of the rotors' drag at their hubs: a yaw-rate damping (and, with the hubs above "
                   "the CG, a roll/pitch moment growing with the body velocity)"),
    Effect("translational_lift", ("k",), ("N s^2/m^2",), (0,), _translational_lift, (2, 3, 4),
           doc="rotor i thrust + k (w_ix² + w_iy²), w_i = v_b + ω × r_i, through the layout",
           meaning="each rotor's thrust grows with the square of its edgewise airspeed (translational lift)"),
]}

def _rate_damping(s, v):
    D = _zeros(s, 3)
    for j in range(3):
        D[:, 3 + j, j] = -s.omega[:, j]
    return D


# Terms outside the catalog that checks fit beside a named effect, never named themselves
# (qr.diagnose.coefficients: an inertia factor that a rate damping takes is no statement about J)
CHECK_TERMS: dict[str, Effect] = {e.name: e for e in [
    Effect("rate_damping", ("cx", "cy", "cz"), ("N m s",) * 3, (0, 0, 0), _rate_damping, TQ,
           doc="torque -diag(c) ω", meaning="a torque opposing the body rate (not a catalog effect: checks only)"),
]}


def lookup(name: str) -> Effect:
    """A catalog effect, or a check term (``CHECK_TERMS``)."""
    return CATALOG[name] if name in CATALOG else CHECK_TERMS[name]


# Effects that are the force and the moment of one physical term: named together they share one parameter
# vector (the spec: rotor_drag and rotor_drag_moment are one rotor drag's force and moment).
TIED = (("rotor_drag", "rotor_drag_moment"),)

# the terms that act at the rotor hubs (hub_z above the CG): their moment depends on the hubs' height
HUB_EFFECTS = ("rotor_drag_moment", "translational_lift")


MAX_DELAY_S = 0.1  # longest plausible actuator delay (s); also bounds the diagnosis's exact-delay search


def plausible_bounds(name: str, vehicle) -> tuple[np.ndarray, np.ndarray]:
    """Parameter ranges a physical vehicle can have (generous: they only rule out nonsense).

    Without them the catalog can "explain" any residual: mass_error dm = -m,
    thrust_gain 0 and inertia_error dJ = -J together reproduce the residual's own
    definition (a vehicle with no mass, no thrust and no inertia).
    """
    m, J = vehicle.mass, vehicle.inertia
    arm = float(np.max(np.hypot(*vehicle.rotors.positions.T)))
    mg = m * 9.81
    hover_speed_sum = 4 * vehicle.hover_speed
    inf = np.inf
    table = {
        "linear_drag": ([0, 0, 0], [20 * m] * 3),  # drag opposes motion; time constant >= 0.05 s
        "quadratic_drag": ([0, 0, 0], [20 * m] * 3),
        "rotor_drag": ([0], [20 * m / hover_speed_sum]),
        "rotor_drag_moment": ([0], [20 * m / hover_speed_sum]),  # rotor_drag's: named together, one k
        # a horizontal wind up to the weight (held at 45° of tilt; a wind tunnel's 12 m/s pushes a 2.65 kg
        # quadrotor with 60 % of it), a vertical one to half of it
        "wind_force": ([-mg, -mg, -0.5 * mg], [mg, mg, 0.5 * mg]),
        "body_force_bias": ([-0.5 * mg] * 3, [0.5 * mg] * 3),
        # a C_T or mass off by more than the rotor-speed check allows (thrust/m g in HOVER_RATIO_LIMITS) is
        # refused as a unit error before any diagnosis
        "thrust_gain": ([HOVER_RATIO_LIMITS[0]], [HOVER_RATIO_LIMITS[1]]),
        "mass_error": ([(HOVER_RATIO_LIMITS[0] - 1) * m], [(HOVER_RATIO_LIMITS[1] - 1) * m]),
        "ground_effect": ([0], [arm**2]),
        "motor_imbalance": ([-0.3] * 4, [0.3] * 4),
        "cg_offset": ([-arm / 2] * 2, [arm / 2] * 2),
        "torque_bias": ([-0.25 * mg * arm] * 3, [0.25 * mg * arm] * 3),
        # C_Q and J are rarely measured: a file off by an order of magnitude (another airframe's numbers,
        # rpm for rad/s) is the most useful thing to find; the lower bounds stay off zero (no yaw torque,
        # no inertia: together they would "explain" the torque residual's own definition)
        "yaw_torque_gain": ([0.02], [50.0]),
        "inertia_error": (list(-0.95 * J), list(20.0 * J)),
        "actuator_delay": ([0], [MAX_DELAY_S]),
        "marker_offset": ([-2 * arm] * 3, [2 * arm] * 3),
        "blade_flapping": ([-20 * m * arm], [20 * m * arm]),
        # more thrust in edgewise flow; four rotors' 4 k v² held to the quadratic drag's 20 m v²
        "translational_lift": ([0], [5 * m]),
    }
    n = len(lookup(name).params)
    lo, hi = table.get(name, ([-inf] * n, [inf] * n))
    return np.array(lo, float), np.array(hi, float)


def get(name: str, path=None) -> Effect:
    if name not in CATALOG:
        close = difflib.get_close_matches(name, list(CATALOG), n=1)
        raise QrInputError(path, f"unknown effect '{name}'" + (f" (did you mean '{close[0]}'?)" if close else ""),
                           f"use one of {', '.join(CATALOG)}")
    return CATALOG[name]


DIMENSIONLESS = "-"  # a catalog unit: the parameter is a ratio or a fraction (a value is printed bare)


def unit(name: str, param: str, vehicle=None) -> str:
    """The unit of effect ``name``'s parameter ``param`` (:data:`DIMENSIONLESS` for a ratio; "" where the
    catalog has no such parameter), the "rotor-speed unit" as the vehicle's where one is given."""
    eff = CATALOG.get(name)
    if eff is None or param not in eff.params:
        return ""
    u = eff.units[eff.params.index(param)]
    if vehicle is not None:
        u = u.replace("rotor-speed unit", SPEED_UNIT_NAMES.get(vehicle.rotor_speed_unit, vehicle.rotor_speed_unit))
    return u


def with_unit(name: str, param: str, value: float, fmt: str = ".4g", vehicle=None) -> str:
    """``'0.3 N s/m'``: a parameter's value followed by its unit (bare for a ratio)."""
    u = unit(name, param, vehicle)
    return f"{value:{fmt}}" + ("" if u in ("", DIMENSIONLESS) else f" {u}")


def effects_with_units(effects: list[dict], vehicle=None) -> str:
    """``'linear_drag(kx=0.0125 N s/m, ky=0.0126 N s/m); thrust_gain(gain=1.02)'``: each value with its unit
    (read back by :func:`qr.report.overview.parse_named`)."""
    return "; ".join(f"{e['name']}(" + ", ".join(f"{k}={with_unit(e['name'], k, v, '.4g', vehicle)}"
                                                 for k, v in e["parameters"].items()) + ")" for e in effects)


def parameter_ranges(eff: Effect, vehicle=None) -> str:
    """``'kx, ky, kz in [0, 14] N s/m'``: the parameters, with the vehicle's plausible ranges if given."""
    if vehicle is None:
        return ", ".join(eff.params)
    lo, hi = plausible_bounds(eff.name, vehicle)
    groups: dict[str, list[str]] = {}  # parameters sharing a range are listed once
    for p, a, b, u in zip(eff.params, lo, hi, eff.units):
        groups.setdefault(f"[{a:.3g}, {b:.3g}]" + (f" {u}" if u != "-" else ""), []).append(p)
    parts = [f"{', '.join(ps)}{' each' if len(ps) > 1 else ''} in {r}" for r, ps in groups.items()]
    neutral = ", ".join(f"{p}={n:g}" for p, n in zip(eff.params, eff.neutral))
    return f"{'; '.join(parts)} (no effect: {neutral})"


def check_parameters(eff: Effect, params, vehicle=None, where=None, form: str | None = None) -> dict:
    """All of ``eff``'s parameters as finite numbers, within ``vehicle``'s plausible ranges if given.

    Every parameter is required: a left-out one is more often a typo than a wish for its
    neutral value.  ``form`` shows how to write them (the ``--effect`` spec or the YAML entry).
    """
    form = form or f"{eff.name} parameters " + ", ".join(eff.params)
    fix = f"write {form} with {parameter_ranges(eff, vehicle)}"
    params = {} if params is None else params
    if not isinstance(params, dict):
        raise QrInputError(where, f"effect {eff.name} has parameters {params!r}, not a mapping of names to values",
                           fix)
    unknown = [str(k) for k in params if k not in eff.params]
    if unknown:
        raise QrInputError(where, f"{', '.join(repr(k) for k in unknown)} is not a parameter of {eff.name}", fix)
    missing = [p for p in eff.params if p not in params]
    if missing:
        given = f"only {', '.join(p for p in eff.params if p in params)} given" if len(missing) < len(eff.params) \
            else "none given"
        raise QrInputError(where, f"effect {eff.name} lacks parameter(s) {', '.join(missing)} ({given})", fix)
    out = {}
    for p in eff.params:
        v = params[p]
        if not is_number(v) or not np.isfinite(v):
            raise QrInputError(where, f"effect {eff.name} parameter {p} is {v!r}, not a finite number", fix)
        out[p] = float(v)
    if vehicle is not None:
        lo, hi = plausible_bounds(eff.name, vehicle)
        tol = 1e-9 * (np.abs(lo) + np.abs(hi))  # a bounded fit may land on a bound to rounding
        for p, a, b, t in zip(eff.params, lo, hi, tol):
            if not a - t <= out[p] <= b + t:
                raise QrInputError(where, f"effect {eff.name} parameter {p}={out[p]:g} is outside the range "
                                          f"[{a:.3g}, {b:.3g}] a physical {vehicle.name} can have", fix)
    return out


def parse_effect_spec(spec: str, vehicle=None) -> dict:
    """``'linear_drag:kx=0.3,ky=0.3,kz=0.1'`` -> ``{'name': 'linear_drag', 'parameters': {...}}``.

    Every parameter must be given; with ``vehicle``, within its plausible range (:func:`plausible_bounds`).
    """
    name, _, rest = spec.partition(":")
    eff = get(name.strip(), "--effect")
    form = f"--effect {eff.name}:" + ",".join(f"{p}=VALUE" for p in eff.params)
    params = {}
    for item in filter(None, (x.strip() for x in rest.split(","))):
        key, eq, val = item.partition("=")
        key = key.strip()
        if not eq or key not in eff.params:
            raise QrInputError("--effect", f"'{item}' is not a parameter of {eff.name}",
                               f"write {form} with {parameter_ranges(eff, vehicle)}")
        try:
            params[key] = float(val)
        except ValueError:
            raise QrInputError("--effect", f"{eff.name} parameter {key}={val.strip()!r} is not a number",
                               f"write {form} with {parameter_ranges(eff, vehicle)}") from None
    return {"name": eff.name, "parameters": check_parameters(eff, params, vehicle, "--effect", form)}


def validate_effect_list(effects, path=None, vehicle=None) -> list[dict]:
    """``[{name, parameters}, ...]`` checked (every parameter a finite number; in range with ``vehicle``)."""
    out = []
    if not isinstance(effects, list):
        raise QrInputError(path, f"'effects' is {effects!r}, not a list",
                           "write effects as a list of {name: ..., parameters: {...}}")
    for e in effects:
        if not isinstance(e, dict) or "name" not in e:
            raise QrInputError(path, f"effect entry {e!r} is not a mapping with a name",
                               "write each effect as {name: ..., parameters: {...}}")
        if not isinstance(e["name"], str):
            raise QrInputError(path, f"effect name {e['name']!r} is not a catalog name",
                               f"use one of {', '.join(CATALOG)}")
        eff = get(e["name"], path)
        form = f"{{name: {eff.name}, parameters: {{" + ", ".join(f"{p}: VALUE" for p in eff.params) + "}}"
        out.append({"name": eff.name, "parameters": check_parameters(eff, e.get("parameters"), vehicle, path, form)})
    return out


def total_term(effects: list[dict], s: Signals, vehicle) -> np.ndarray:
    """Sum of the terms of a list of ``{name, parameters}`` (N, 6)."""
    out = np.zeros((len(s), 6))
    for e in effects:
        out += get(e["name"]).term(e["parameters"], s, vehicle)
    return out
