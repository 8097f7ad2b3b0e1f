"""The mapping table: every vehicle parameter and named effect, per simulator (the rows of ``mapping.md``).

One place for the unit conversions (qr's rotor-speed unit → rad/s) and for the vehicle the
simulators receive: the TRUE plant's parameter vector (:func:`qr.sim.plant.true_params`), so an
export carries exactly the physics ``qr synth``, the replay and the rollout integrate.  Each
simulator module (:mod:`qr.export.rotorpy`, :mod:`qr.export.px4_gz`, :mod:`qr.export.mujoco`)
turns that vector into its files (:class:`File`, in memory) and a list of :class:`Row`, one for every key and named effect of
the vehicle file (the simulator's key, the value in its units, the formula that gives it from the
file's numbers, exact / approximate with the condition / impossible with the term's size and what
the export does instead); :func:`qr.export.document.mapping_md` writes them as ``mapping.md``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import plant_state as ps
from .. import residual as rs
from ..effects import HUB_EFFECTS
from ..sim import plant as pl
from ..vehicle import KNOWN, SPEED_IN_RPM

EXACT, APPROXIMATE, IMPOSSIBLE = "exact", "approximate", "impossible"
V_REF = 1.0  # m/s: the airspeed at which a velocity-dependent term's size is stated


def rad_s_per_unit(vehicle) -> float:
    """One rotor-speed unit of the vehicle file in rad/s (rpm: 2π/60)."""
    return SPEED_IN_RPM[vehicle.rotor_speed_unit] * 2 * math.pi / 60.0


@dataclass(frozen=True)
class Row:
    """One line of ``mapping.md``."""

    item: str  # the qr parameter or effect (``thrust_coeff``, ``blade_flapping.k``)
    qr_value: str  # its value in qr's units
    key: str  # the simulator's key (or "-")
    value: str  # the value in the simulator's units
    status: str  # EXACT, APPROXIMATE or IMPOSSIBLE
    note: str  # the conversion, the condition of an approximation, or the size and what is done instead
    formula: str = ""  # ``value`` from the vehicle file's numbers (the grammar: docs/export.md, "Formulas")


@dataclass(frozen=True)
class File:
    """One file of an export, built in memory: its name relative to the output folder (``<name>/model.sdf``
    inside the folder ``<name>``) and its text or bytes."""

    name: str
    data: str | bytes


@dataclass(frozen=True)
class Plant:
    """The vehicle as the simulators receive it: SI units, rotor speeds in rad/s, CG as the origin of forces."""

    name: str
    mass: float  # kg, with mass_error
    inertia: np.ndarray  # (3,) kg m², with inertia_error
    rotor_xy: np.ndarray  # (4, 2) m, rotor axes in the vehicle file's body frame (not yet relative to the CG)
    yaw_signs: np.ndarray  # (4,) sign of each rotor's reaction torque about body z (up)
    k_thrust: np.ndarray  # (4,) N/(rad/s)², per rotor (thrust_gain and motor_imbalance applied)
    k_yaw: np.ndarray  # (4,) N m/(rad/s)², per rotor (yaw_torque_gain and motor_imbalance applied)
    cg: np.ndarray  # (2,) m, CG relative to the rotor map's origin (cg_offset)
    tau_m: float  # s, motor time constant
    speed_min: float  # rad/s
    speed_max: float  # rad/s
    hover: float  # rad/s, rotor speed of four equal rotors carrying m g with the mean k_thrust
    P: np.ndarray  # the TRUE plant's parameter vector (qr.sim.plant), for the remaining terms
    unit: float  # rad/s per vehicle rotor-speed unit
    hub_z: float = 0.0  # m, the rotor hubs' height above the CG (the vehicle file's hub_z)

    @property
    def rotor_pos(self) -> np.ndarray:
        """(4, 3) m: rotor hubs relative to the CG (their height: hub_z)."""
        r = np.zeros((len(self.yaw_signs), 3))
        r[:, :2] = self.rotor_xy - self.cg
        r[:, 2] = self.hub_z
        return r

    @property
    def weight(self) -> float:
        return self.mass * 9.81

    @property
    def arm(self) -> float:
        return float(np.max(np.hypot(*self.rotor_xy.T)))


def plant_of(vehicle) -> Plant:
    """The vehicle file plus its named effects, as the TRUE plant integrates them."""
    P = pl.true_params(vehicle, vehicle.effects)
    f = rad_s_per_unit(vehicle)
    rm = vehicle.rotors
    scale = P[ps.P_SCALE]
    k_thrust = rm.thrust_coeff * scale / f**2
    # motor_imbalance's share of each rotor's yaw gain (rotor_torque_gains, the refinement's, are not carried)
    k_yaw = rm.torque_coeff * P[ps.P_CQGAIN] * P[ps.P_YAW_GAIN] / vehicle.rotor_torque_gains / f**2
    m = float(P[ps.P_MASS])
    return Plant(name=vehicle.name, mass=m, inertia=P[ps.P_J].copy(), rotor_xy=rm.positions.copy(),
                 yaw_signs=rm.yaw_signs.copy(), k_thrust=k_thrust, k_yaw=k_yaw,
                 cg=P[ps.P_CG].copy(), tau_m=float(P[ps.P_TAU]), speed_min=vehicle.rotor_speed_min * f,
                 speed_max=vehicle.rotor_speed_max * f, hover=math.sqrt(m * 9.81 / float(np.sum(k_thrust))),
                 P=P, unit=f, hub_z=vehicle.hub_z)


def file_stem(vehicle) -> str:
    """A Python module name from the vehicle's name (``crazyflie21-brushless`` → ``crazyflie21_brushless``)."""
    stem = re.sub(r"\W", "_", vehicle.name).strip("_") or "vehicle"
    return stem if not stem[0].isdigit() else f"v_{stem}"


def g(x: float) -> str:
    """A number as the files carry it: 10 significant digits (the conversions are checked to 1e-9)."""
    return f"{float(x) + 0.0:.10g}"  # + 0.0: no "-0"


def effect_value(vehicle, name: str) -> str:
    """``'k=0.00069'``: an effect's parameters as the vehicle file has them (an effect listed twice: both)."""
    return "; ".join(", ".join(f"{k}={g(v)}" for k, v in e["parameters"].items())
                     for e in vehicle.effects if e["name"] == name)


def present(vehicle) -> list[str]:
    """The named effects of the vehicle (each once, in the file's order)."""
    out = []
    for e in vehicle.effects:
        if e["name"] not in out:
            out.append(e["name"])
    return out


# ---- formulas: each row's number from the vehicle file's, as text a person reads and a test evaluates ----
# Symbols: the file's numbers (m, J_xx…, C_T, C_Q, τ_m, u_min, u_max, ground_z; rotor i's x_i, y_i, s_i =
# yaw_sign and d_i = motor_imbalance's d<i>), an effect's parameter as ``effect.param``, f, g, n, ω_h.
# Operators: + − · / ², √(…), round(…); ``_i`` expands over the rotors; a comma separates the values.

def has(vehicle, name: str) -> bool:
    return any(e["name"] == name for e in vehicle.effects)


def _plus(base: str, term: str | None) -> str:
    return f"{base} + {term}" if term else base


def fx_mass(vehicle) -> str:
    return _plus("m", "mass_error.dm" if has(vehicle, "mass_error") else None)


def fx_inertia(vehicle) -> list[str]:
    err = has(vehicle, "inertia_error")
    return [_plus(f"J_{a}", f"inertia_error.dJ{a}" if err else None) for a in ("xx", "yy", "zz")]


def fx_k_thrust(vehicle, mean: bool = False) -> str:
    """Rotor i's thrust per (rad/s)² (``mean``: their mean)."""
    out = "C_T" + (" · thrust_gain.gain" if has(vehicle, "thrust_gain") else "")
    return out + _imbalance(vehicle, mean) + " / f²"


def _imbalance(vehicle, mean: bool) -> str:
    """motor_imbalance's factor on rotor i's C_T (``mean``: on their mean)."""
    if not has(vehicle, "motor_imbalance"):
        return ""
    return f" · (1 + {fx_d_mean(vehicle)})" if mean else " · (1 + d_i)"


def fx_d_mean(vehicle) -> str:
    """The d_i's mean, as a formula."""
    n = vehicle.rotors.n
    return "(" + " + ".join(f"d_{i}" for i in range(1, n + 1)) + ") / n"


def fx_yaw_share(vehicle) -> str:
    """motor_imbalance's factor on rotor i's C_Q: its share relative to the others' (their mean is 1)."""
    return f" · (1 + d_i − {fx_d_mean(vehicle)})" if has(vehicle, "motor_imbalance") else ""


def fx_k_yaw(vehicle, mean: bool = False) -> str:
    """Rotor i's C_Q per (rad/s)², the yaw-torque gain and the imbalance applied (``mean``: their mean)."""
    out = "C_Q" + (" · yaw_torque_gain.gain" if has(vehicle, "yaw_torque_gain") else "")
    return out + ("" if mean else fx_yaw_share(vehicle)) + " / f²"


def fx_cg(vehicle) -> tuple[str, str]:
    return ("cg_offset.rx", "cg_offset.ry") if has(vehicle, "cg_offset") else ("0", "0")


def fx_minus(a: str, b: str) -> str:
    return a if b == "0" else f"{a} − {b}"


def fx_effect(vehicle, name: str, params) -> list[str]:
    return [f"{name}.{p}" for p in params]


def symbols(vehicle, pp: Plant) -> str:
    """The line of ``mapping.md`` that defines the formulas' symbols, with this vehicle's values."""
    u = vehicle.rotor_speed_unit
    n = vehicle.rotors.n
    mass = fx_mass(vehicle) if not has(vehicle, "mass_error") else f"({fx_mass(vehicle)})"
    return ("Formulas (column *formula*; docs/export.md, \"Formulas\") use the vehicle file's numbers: m, J_xx, "
            "J_yy, J_zz, C_T, C_Q, τ_m (motor_time_constant), u_min, u_max (rotor_speed_min, rotor_speed_max), "
            "ground_z, hub_z; rotor i's x_i, y_i, s_i (yaw_sign) and d_i (motor_imbalance's d<i>); an effect's parameter "
            "as effect.param (an effect listed twice: added, gains multiplied); "
            f"f = {g(pp.unit)} rad/s per {u}; g = 9.81 m/s²; n = {n} rotors; "
            f"ω_h = √({mass} · g / Σ_i k_i) = {g(pp.hover)} rad/s, the hover rotor speed, with k_i = "
            f"{fx_k_thrust(vehicle)}. `_i` repeats a formula for each rotor; commas separate the values.")


# ---- the learned terms' size ---------------------------------------------------------------------------------

def force_size(n: float, weight: float) -> str:
    return f"{n:.3g} N ({100 * n / weight:.3g} % of the weight)"


def torque_size(n: float, pp: Plant) -> str:
    return f"{n:.3g} N m ({100 * n / (pp.weight / 4 * pp.arm):.3g} % of one rotor's hover thrust at the arm)"


def residual_size(vehicle, pp: Plant) -> str:
    """The learned wrench's size: its RMS over the training flights (as ``qr learn residual`` recorded it in the
    vehicle file), and its value at hover (level, at rest, every rotor at the hover speed)."""
    net = vehicle.residual
    phi = rs.features(net.inputs, np.zeros((1, 3)), np.zeros((1, 3)), np.array([[0.0, 0.0, -1.0]]),
                      np.full((1, vehicle.rotors.n), vehicle.hover_speed), net.rotor_speed_scale)
    w = rs.forward(net, phi)[0]
    hover = (f"at hover (level, at rest, rotors at ω_h): force {force_size(float(np.linalg.norm(w[:3])), pp.weight)}, "
             f"torque {torque_size(float(np.linalg.norm(w[3:])), pp)}")
    rec = rs.recorded_size(vehicle.raw.get("residual"))
    if rec is None:
        return ("its RMS over the training flights is not recorded in this file (a qr learn residual before the "
                "record: train again to have it); " + hover)
    flights = ", ".join(rec.flights) or "-"
    return (f"RMS over the {rec.samples} samples of its training windows ({len(rec.flights)} flight(s): "
            f"{flights}): force {force_size(rec.rms_force, pp.weight)} (x, y, z: "
            + ", ".join(f"{x:.3g}" for x in rec.rms_force_xyz) + f" N), torque {torque_size(rec.rms_torque, pp)}"
            " (x, y, z: " + ", ".join(f"{x:.3g}" for x in rec.rms_torque_xyz) + " N m); " + hover)


def residual_item(vehicle) -> str:
    """The ``qr value`` of a residual row: the network as the vehicle file describes it."""
    net = vehicle.residual
    return (f"MLP {net.layers} ({net.activation}) from {', '.join(net.inputs)} to a body force and torque "
            f"({Path(vehicle.raw['residual']['model']).name})")


def sizes(pp: Plant) -> dict[str, str]:
    """The size of each term a simulator may lack, stated at the hover rotor speed and ``V_REF`` m/s:
    forces as a fraction of the weight, torques as a fraction of one rotor's hover thrust at the arm."""
    P, W = pp.P, pp.weight

    def force(n):
        return force_size(n, W)

    def torque(n):
        return torque_size(n, pp)

    lin = P[ps.P_LIN]
    quad = P[ps.P_QUAD]
    omega_sum_units = 4 * pp.hover / pp.unit
    rem = P[ps.P_REM].reshape(3, 11)
    return {
        "linear_drag": f"{force(float(np.max(lin)) * V_REF)} at {V_REF:g} m/s",
        "quadratic_drag": f"{force(float(np.max(quad)) * V_REF**2)} at {V_REF:g} m/s",
        "rotor_drag": f"{force(P[ps.P_RDRAG] * omega_sum_units * V_REF)} at {V_REF:g} m/s and hover rotor speed",
        "wind_force": force(float(np.linalg.norm(P[ps.P_WIND]))),
        "body_force_bias": force(float(np.linalg.norm(P[ps.P_BBIAS]))),
        "ground_effect": f"{force(P[ps.P_GE] * W / 0.1**2)} at 0.1 m above the floor in hover",
        "cg_offset": torque(float(np.linalg.norm(P[ps.P_CG])) * W),
        "torque_bias": torque(float(np.linalg.norm(P[ps.P_TBIAS]))),
        "blade_flapping": f"{torque(abs(P[ps.P_FLAP]) * V_REF)} at {V_REF:g} m/s",
        "rotor_drag_moment": f"{torque(P[ps.P_RDM] * pp.hover / pp.unit * float(np.sum(pp.rotor_pos[:, :2] ** 2)))} "
                             "at 1 rad/s of yaw rate and hover rotor speed",
        "translational_lift": f"{force(4 * P[ps.P_TLIFT] * V_REF**2)} at {V_REF:g} m/s",
        "actuator_delay": f"{1000 * P[ps.P_DELAY]:.3g} ms between the rotor speed and its wrench",
        "marker_offset": f"{1000 * float(np.linalg.norm(P[ps.P_MARKER])):.3g} mm "
                         "between the tracked point and the CG",
        "torque_remainder": torque(float(np.max(np.abs(rem[:, 10]))) if P[ps.P_REM_ON] else 0.0)
        + " (its constant part; the rest grows with v_b, ω and the rotor loads)",
    }


def untied_moment(P) -> str:
    """A simulator whose rotor drag acts at the hubs, when rotor_drag_moment's k is not rotor_drag's: what its moment is."""
    if not P[ps.P_RDRAG]:
        return "the moment is absent (rotor_drag not named)"
    return f"its moment has rotor_drag's k ({g(P[ps.P_RDRAG])}), not rotor_drag_moment's ({g(P[ps.P_RDM])})"


def _rotor_property_rows(vehicle, pp: Plant) -> list[Row]:
    """The rotor and airframe properties the catalog lacks (``qr.vehicle.ROTOR_PROPERTIES``), where the file
    gives them: no simulator element of the three holds them; their size at hover and 1 rad/s or 1 m/s (a
    file's neutral value: exact, nothing to carry)."""
    rows, raw = [], vehicle.raw
    if vehicle.rotor_inertia:
        h = vehicle.rotor_inertia * pp.hover
        rows.append(Row("rotor_inertia", g(vehicle.rotor_inertia) + " kg m²", "-", "-", IMPOSSIBLE,
                        f"the rotors' gyroscopic moment and speed-change reaction: left out (one rotor's momentum at "
                        f"hover {g(h)} N m s: a moment of that size per rad/s of body rate where the rotors' "
                        "momenta do not cancel)"))
    elif "rotor_inertia" in raw:
        rows.append(Row("rotor_inertia", "0 kg m²", "-", "-", EXACT, "no rotor inertia: no gyroscopic moment, as the "
                        "simulators' rotors"))
    gains = vehicle.rotor_torque_gains
    if np.any(gains != 1.0):
        rows.append(Row("rotor_torque_gains", ", ".join(g(x) for x in gains), "-", "-", APPROXIMATE,
                        "each rotor's C_Q: the export uses the file's torque_coeff (× yaw_torque_gain) for every "
                        f"rotor; the yaw torques differ by up to {100 * float(np.max(np.abs(gains - 1))):.3g} %"))
    elif "rotor_torque_gains" in raw:
        rows.append(Row("rotor_torque_gains", ", ".join(g(x) for x in gains), "-", "-", EXACT,
                        "every rotor's C_Q is torque_coeff: nothing to carry"))
    if vehicle.flapping_pitch_ratio != 1.0:
        k = float(pp.P[ps.P_FLAP])
        rows.append(Row("flapping_pitch_ratio", g(vehicle.flapping_pitch_ratio), "-", "-", IMPOSSIBLE if k else EXACT,
                        f"the pitch flapping coefficient over the roll one: left out (pitch moment "
                        f"{g(abs(k * (vehicle.flapping_pitch_ratio - 1)) * V_REF)} N m at {g(V_REF)} m/s beyond "
                        "blade_flapping's)" if k else "no blade flapping named: no effect"))
    elif "flapping_pitch_ratio" in raw:
        rows.append(Row("flapping_pitch_ratio", "1", "-", "-", EXACT, "pitch flapping as the roll one "
                        "(blade_flapping's row)"))
    return rows


def common_rows(vehicle, pp: Plant, keys: dict[str, tuple]) -> list[Row]:
    """Rows every simulator has in the same way: the rotor-speed unit, mass, inertia, C_T, C_Q, and the file's
    keys that are no physics (name, arm_length, description, source, rotor_input, command_map).

    ``keys``: item -> (simulator key, its value, its formula[, the note]) for name, mass, inertia, thrust_coeff,
    torque_coeff; the note defaults to the unit's conversion."""
    u = vehicle.rotor_speed_unit
    f = pp.unit
    raw = vehicle.raw
    conv = "1" if u == "rad_s" else "2π/60 rad/s per rpm"
    notes = {
        "name": "the files' names come from it (characters that are not a letter, digit or _ become _)",
        "mass": "kg; mass_error added" if has(vehicle, "mass_error") else "kg",
        "inertia": "principal axes = body axes; inertia_error added" if has(vehicle, "inertia_error")
        else "principal axes = body axes",
        "thrust_coeff": f"C_T per {u}² → per (rad/s)²: ÷ f²",
        "torque_coeff": f"C_Q per {u}² → per (rad/s)²: ÷ f²",
    }
    qr_values = {
        "name": vehicle.name, "mass": g(vehicle.mass) + " kg",
        "inertia": "[" + ", ".join(g(x) for x in vehicle.inertia) + "] kg m²",
        "thrust_coeff": g(vehicle.thrust_coeff) + f" N/{u}²", "torque_coeff": g(vehicle.torque_coeff) + f" N m/{u}²",
    }
    out = [Row("rotor_speed_unit", u, "-", f"{g(f)} rad/s per {u}", EXACT, f"ω [rad/s] = f u [{u}] ({conv})",
               formula="f")]
    for item in ("name", "mass", "inertia", "thrust_coeff", "torque_coeff"):
        key, value, formula, *note = keys[item]
        out.append(Row(item, qr_values[item], key, value, EXACT, note[0] if note else notes[item], formula=formula))
    if "arm_length" in raw:
        out.append(Row("arm_length", g(raw["arm_length"]) + " m", "-", "-", EXACT,
                       "in the rotor positions (layout rows): " + ("it places the rotors of the named layout"
                                                                   if isinstance(raw["layout"], str) else
                                                                   "not used where the layout lists them")))
    for key in ("description", "source"):
        if key in raw:
            out.append(Row(key, "(text)", "-", "-", EXACT, "text, not physics: nothing to map"))
    for key in sorted(set(map(str, raw)) - KNOWN):
        out.append(Row(key, "(unknown key)", "-", "-", IMPOSSIBLE, "not a key qr knows: qr ignores it (warned at "
                       "load), so the export carries nothing of it; check its spelling"))
    if vehicle.command_map is not None:
        out.append(Row("rotor_input, command_map", "command: a + b c + k c² N", "-", "-", IMPOSSIBLE,
                       "the simulators take rotor speeds: give them qr's equivalent speeds u = sqrt(F / C_T) "
                       "(qr ingest's), not the motor commands"))
    else:
        out.append(Row("rotor_input" + (", command_map" if "command_map" in raw else ""), vehicle.rotor_input, "-",
                       "rotor speeds", EXACT, "the simulators take rotor speeds, as the log's u1..u4"
                       + ("; command_map is ignored (rotor_input is speed), as qr ignores it" if "command_map" in raw
                          else "")))
    out += _rotor_property_rows(vehicle, pp)
    return out


def ground_row(vehicle, key: str = "-", value: str = "-") -> Row:
    """``ground_z``: the floor's height in the log's world frame, which only the ground effect uses."""
    z = g(vehicle.ground_z) + " m"
    if key != "-":
        return Row("ground_z", z, key, value, EXACT, "the floor's height in the log's world frame: the ground "
                   "effect's reference (no other term uses it)", formula="ground_z")
    if has(vehicle, "ground_effect"):
        return Row("ground_z", z, "-", "-", IMPOSSIBLE, "the ground effect's reference height, left out with it "
                   "(ground_effect row)")
    return Row("ground_z", z, "-", "-", EXACT, "the floor's height in the log's world frame, used by no term of this "
               "vehicle (no ground_effect): nothing to map; put the simulator's floor there to match the log")


def hub_row(vehicle, key: str, kept: tuple[str, ...] = ()) -> Row:
    """``hub_z`` for a simulator whose rotors sit in the CG's plane (``key``'s z is 0): the thrusts' moment about
    the CG does not depend on the height, only the terms at the hubs do (``kept``: those the simulator carries)."""
    z = g(vehicle.hub_z) + " m"
    named = [n for n in HUB_EFFECTS if has(vehicle, n)]
    if not named or vehicle.hub_z == 0:
        note = ("the rotors sit in the CG's plane" + (", as the hubs do" if named else "") + ": the thrusts' moment "
                "about the CG does not depend on their height" + ("" if named else "; no term of this vehicle acts "
                                                                     "at the hubs (no " + " or ".join(HUB_EFFECTS) + ")"))
        return Row("hub_z", z, key, "0 m", EXACT, note, formula="0")
    kept = [n for n in named if n in kept]
    lost = [n for n in named if n not in kept]
    parts = ([f"{', '.join(kept)}: the roll/pitch part of the moment is left out"] if kept else []) \
        + ([f"{', '.join(lost)} left out (their rows)"] if lost else [])
    note = "the rotors sit in the CG's plane, not hub_z above it: " + "; ".join(parts)
    return Row("hub_z", z, key, "0 m", APPROXIMATE if kept else IMPOSSIBLE, note, formula="0")

