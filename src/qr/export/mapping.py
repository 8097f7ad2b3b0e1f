"""The mapping table: every vehicle parameter and named effect, per simulator, and ``mapping.md``.

One place for the unit conversions (qr's rotor-speed unit → rad/s) and for the vehicle the
simulators receive: the TRUE plant's parameter vector (:func:`qr.sim.plant.true_params`), so an
export carries exactly the physics ``qr synth``, the replay and the rollout integrate.  Each
simulator module (:mod:`qr.export.rotorpy`, :mod:`qr.export.px4_gz`, :mod:`qr.export.mujoco`)
turns that vector into its files and a list of :class:`Row` (the simulator's key, the value in its
units, exact / approximate with the condition / impossible with the term's size and what the
export does instead); :func:`render` writes them as ``mapping.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..sim import plant as pl
from ..vehicle import SPEED_IN_RPM

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


@dataclass(frozen=True)
class Plant:
    """The vehicle as the simulators receive it: SI units, rotor speeds in rad/s, CG as the origin of forces."""

    name: str
    mass: float  # kg, with mass_error
    inertia: np.ndarray  # (3,) kg m², with inertia_error
    rotor_xy: np.ndarray  # (4, 2) m, rotor axes in the vehicle file's body frame (not yet relative to the CG)
    yaw_signs: np.ndarray  # (4,) sign of each rotor's reaction torque about body z (up)
    k_thrust: np.ndarray  # (4,) N/(rad/s)², per rotor (thrust_gain and motor_imbalance applied)
    k_yaw: float  # N m/(rad/s)², yaw_torque_gain applied
    cg: np.ndarray  # (2,) m, CG relative to the rotor map's origin (cg_offset)
    tau_m: float  # s, motor time constant
    speed_min: float  # rad/s
    speed_max: float  # rad/s
    hover: float  # rad/s, rotor speed of four equal rotors carrying m g with the mean k_thrust
    P: np.ndarray  # the TRUE plant's parameter vector (qr.sim.plant), for the remaining terms
    unit: float  # rad/s per vehicle rotor-speed unit

    @property
    def rotor_pos(self) -> np.ndarray:
        """(4, 3) m: rotor hubs relative to the CG (rotor plane through the CG)."""
        r = np.zeros((len(self.yaw_signs), 3))
        r[:, :2] = self.rotor_xy - self.cg
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
    scale = P[pl.P_SCALE:pl.P_SCALE + 4]
    k_thrust = rm.thrust_coeff * scale / f**2
    m = float(P[pl.P_MASS])
    return Plant(name=vehicle.name, mass=m, inertia=P[pl.P_J:pl.P_J + 3].copy(), rotor_xy=rm.positions.copy(),
                 yaw_signs=rm.yaw_signs.copy(), k_thrust=k_thrust, k_yaw=rm.torque_coeff * P[pl.P_CQGAIN] / f**2,
                 cg=P[pl.P_CG:pl.P_CG + 2].copy(), tau_m=float(P[pl.P_TAU]), speed_min=vehicle.rotor_speed_min * f,
                 speed_max=vehicle.rotor_speed_max * f, hover=math.sqrt(m * 9.81 / float(np.sum(k_thrust))),
                 P=P, unit=f)


def g(x: float) -> str:
    """A number as the files carry it: 10 significant digits (the conversions are checked to 1e-9)."""
    return f"{float(x) + 0.0:.10g}"  # + 0.0: no "-0"


def effect_value(vehicle, name: str) -> str:
    """``'k=0.00069'``: an effect's parameters as the vehicle file has them."""
    for e in vehicle.effects:
        if e["name"] == name:
            return ", ".join(f"{k}={g(v)}" for k, v in e["parameters"].items())
    return ""


def present(vehicle) -> list[str]:
    """The named effects of the vehicle (each once, in the file's order)."""
    out = []
    for e in vehicle.effects:
        if e["name"] not in out:
            out.append(e["name"])
    return out


def sizes(pp: Plant) -> dict[str, str]:
    """The size of each term a simulator may lack, stated at the hover rotor speed and ``V_REF`` m/s:
    forces as a fraction of the weight, torques as a fraction of one rotor's hover thrust at the arm."""
    P, W = pp.P, pp.weight
    tq = W / 4 * pp.arm

    def force(n):
        return f"{n:.3g} N ({100 * n / W:.3g} % of the weight)"

    def torque(n):
        return f"{n:.3g} N m ({100 * n / tq:.3g} % of one rotor's hover thrust at the arm)"

    lin = P[pl.P_LIN:pl.P_LIN + 3]
    quad = P[pl.P_QUAD:pl.P_QUAD + 3]
    omega_sum_units = 4 * pp.hover / pp.unit
    rem = P[pl.P_REM:pl.P_REM + 33].reshape(3, 11)
    return {
        "linear_drag": f"{force(float(np.max(lin)) * V_REF)} at {V_REF:g} m/s",
        "quadratic_drag": f"{force(float(np.max(quad)) * V_REF**2)} at {V_REF:g} m/s",
        "rotor_drag": f"{force(P[pl.P_RDRAG] * omega_sum_units * V_REF)} at {V_REF:g} m/s and hover rotor speed",
        "wind_force": force(float(np.linalg.norm(P[pl.P_WIND:pl.P_WIND + 3]))),
        "body_force_bias": force(float(np.linalg.norm(P[pl.P_BBIAS:pl.P_BBIAS + 3]))),
        "ground_effect": f"{force(P[pl.P_GE] * W / 0.1**2)} at 0.1 m above the floor in hover",
        "cg_offset": torque(float(np.linalg.norm(P[pl.P_CG:pl.P_CG + 2])) * W),
        "torque_bias": torque(float(np.linalg.norm(P[pl.P_TBIAS:pl.P_TBIAS + 3]))),
        "blade_flapping": f"{torque(abs(P[pl.P_FLAP]) * V_REF)} at {V_REF:g} m/s",
        "actuator_delay": f"{1000 * P[pl.P_DELAY]:.3g} ms between the rotor speed and its wrench",
        "marker_offset": f"{1000 * float(np.linalg.norm(P[pl.P_MARKER:pl.P_MARKER + 3])):.3g} mm "
                         "between the tracked point and the CG",
        "torque_remainder": torque(float(np.max(np.abs(rem[:, 10]))) if P[pl.P_REM_ON] else 0.0)
        + " (its constant part; the rest grows with v_b, ω and the rotor loads)",
    }


def render(target: str, vehicle_path: str, vehicle, rows: list[Row], intro: list[str], version: str) -> str:
    """``mapping.md``: what each number of the vehicle became in the simulator's files."""
    counts = {s: sum(r.status == s for r in rows) for s in (EXACT, APPROXIMATE, IMPOSSIBLE)}
    lines = [f"# {vehicle.name} for {target}: the mapping", "",
             f"Written by `qr export {vehicle_path} --to {target}` (qr {version}). {len(rows)} items: "
             f"{counts[EXACT]} exact, {counts[APPROXIMATE]} approximate, {counts[IMPOSSIBLE]} impossible.", "",
             *intro, "",
             "| qr item | qr value | simulator key | simulator value | mapping | conversion, condition or size |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r.item} | {r.qr_value} | {r.key} | {r.value} | {r.status} | {r.note} |")
    return "\n".join(lines) + "\n"


def _rotor_property_rows(vehicle, pp: Plant) -> list[Row]:
    """The rotor and airframe properties the catalog lacks (``qr.vehicle.ROTOR_PROPERTIES``), where the file
    gives them: no simulator element of the three holds them; their size at hover and 1 rad/s or 1 m/s."""
    rows = []
    if vehicle.rotor_inertia:
        h = vehicle.rotor_inertia * pp.hover
        rows.append(Row("rotor_inertia", g(vehicle.rotor_inertia) + " kg m²", "-", "-", IMPOSSIBLE,
                        f"the rotors' gyroscopic moment and speed-change reaction: left out (one rotor's momentum at "
                        f"hover {g(h)} N m s: a moment of that size per rad/s of body rate where the rotors' "
                        "momenta do not cancel)"))
    gains = vehicle.rotor_torque_gains
    if np.any(gains != 1.0):
        rows.append(Row("rotor_torque_gains", ", ".join(g(x) for x in gains), "-", "-", APPROXIMATE,
                        "each rotor's C_Q: the export uses the file's torque_coeff (× yaw_torque_gain) for every "
                        f"rotor; the yaw torques differ by up to {100 * float(np.max(np.abs(gains - 1))):.3g} %"))
    if vehicle.flapping_pitch_ratio != 1.0:
        k = float(pp.P[pl.P_FLAP])
        rows.append(Row("flapping_pitch_ratio", g(vehicle.flapping_pitch_ratio), "-", "-", IMPOSSIBLE,
                        f"the pitch flapping coefficient over the roll one: left out (pitch moment "
                        f"{g(abs(k * (vehicle.flapping_pitch_ratio - 1)) * V_REF)} N m at {g(V_REF)} m/s beyond "
                        "blade_flapping's)" if k else "no blade flapping named: no effect"))
    return rows


def common_rows(vehicle, pp: Plant, keys: dict[str, tuple[str, str]]) -> list[Row]:
    """Rows every simulator has in the same way: mass, inertia, C_T, C_Q, rotor speed unit.

    ``keys``: item -> (simulator key, its value) for mass, inertia, thrust_coeff, torque_coeff."""
    u = vehicle.rotor_speed_unit
    f = pp.unit
    conv = "1" if u == "rad_s" else "2π/60 rad/s per rpm"
    extra = []
    if vehicle.command_map is not None:
        extra.append(Row("command_map", "a + b c + k c² N", "-", "-", IMPOSSIBLE,
                         "the simulators take rotor speeds: give them qr's equivalent speeds u = sqrt(F / C_T) "
                         "(qr ingest's), not the motor commands"))
    extra += _rotor_property_rows(vehicle, pp)
    return extra + [
        Row("rotor_speed_unit", u, "-", "rad/s", EXACT, f"ω [rad/s] = {g(f)} u [{u}] ({conv})"),
        Row("mass", g(vehicle.mass) + " kg", *keys["mass"], EXACT,
            "kg; mass_error added" if "mass_error" in present(vehicle) else "kg"),
        Row("inertia", "[" + ", ".join(g(x) for x in vehicle.inertia) + "] kg m²", *keys["inertia"], EXACT,
            "principal axes = body axes; inertia_error added" if "inertia_error" in present(vehicle)
            else "principal axes = body axes"),
        Row("thrust_coeff", g(vehicle.thrust_coeff) + f" N/{u}²", *keys["thrust_coeff"], EXACT,
            f"C_T / {g(f)}² (N per (rad/s)²)"),
        Row("torque_coeff", g(vehicle.torque_coeff) + f" N m/{u}²", *keys["torque_coeff"], EXACT,
            f"C_Q / {g(f)}² (N m per (rad/s)²)"),
    ]
