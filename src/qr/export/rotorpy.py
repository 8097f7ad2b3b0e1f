"""``qr export --to rotorpy``: a RotorPy 3 parameter module, ``<name>_params.py``.

RotorPy's ``Multirotor.compute_body_wrench`` against qr's plant, term by term (``k_eta``, ``k_m``,
``rotor_pos``, ``k_d``, ``k_h``, ``k_flap``, ``c_D``, and what the module's ``QrMultirotor`` adds):
docs/export.md "How each convention was derived".
"""

from __future__ import annotations

import numpy as np

from .. import plant_state as ps
from ..sim import plant as pl
from . import learned, mapping as mp
from .mapping import APPROXIMATE, EXACT, IMPOSSIBLE, File, Row, file_stem, g

# RotorPy's low-level gains (for its cmd_ctbr / cmd_vel / cmd_acc / cmd_ctatt abstractions): its own
# defaults (Multirotor.__init__), scaled to this vehicle's inertia by the controller's own use of J
DEFAULT_GAINS = {"k_w": 1.0, "k_v": 10.0, "kp_att": 3000.0, "kd_att": 360.0}


def _vec(x) -> str:
    return "[" + ", ".join(g(v) for v in np.ravel(x)) + "]"


def quad_params(pp: mp.Plant) -> dict:
    """The ``quad_params`` dict (plain floats and lists; the module turns vectors into arrays)."""
    P = pp.P
    return {
        "mass": pp.mass, "Ixx": pp.inertia[0], "Iyy": pp.inertia[1], "Izz": pp.inertia[2],
        "Ixy": 0.0, "Iyz": 0.0, "Ixz": 0.0,
        "num_rotors": len(pp.yaw_signs),
        "rotor_pos": {f"r{i + 1}": list(r) for i, r in enumerate(pp.rotor_pos)},
        "rotor_directions": list(pp.yaw_signs),
        "rI": [0.0, 0.0, 0.0],
        "rotor_radius": display_radius(pp),
        "c_Dx": P[ps.P_QUAD.start], "c_Dy": P[ps.P_QUAD.start + 1], "c_Dz": P[ps.P_QUAD.start + 2],
        "k_eta": float(np.mean(pp.k_thrust)), "k_m": float(np.mean(pp.k_yaw)),
        "k_d": P[ps.P_RDRAG] / pp.unit, "k_z": 0.0, "k_h": P[ps.P_TLIFT],
        "k_flap": -P[ps.P_FLAP] / (4 * pp.hover),
        "tau_m": pp.tau_m, "rotor_speed_min": pp.speed_min, "rotor_speed_max": pp.speed_max,
        "motor_noise_std": 0.0, **DEFAULT_GAINS,
    }


def display_radius(pp: mp.Plant) -> float:
    """RotorPy draws rotors of this radius (m; no physics uses it): the largest that do not overlap, half the
    smallest distance between two rotor axes (qr's files have no propeller size)."""
    r = pp.rotor_xy
    d = np.linalg.norm(r[:, None] - r[None], axis=-1)
    return float(d[np.triu_indices(len(r), 1)].min() / 2)


def residual_file(vehicle) -> str:
    return learned.residual_file(file_stem(vehicle))


def qr_terms(vehicle, pp: mp.Plant) -> dict:
    """What ``QrMultirotor`` adds: SI units, rotor speeds in rad/s, body frame unless named world."""
    P = pp.P
    k_eta = float(np.mean(pp.k_thrust))
    rem = P[ps.P_REM].reshape(3, 11) if P[ps.P_REM_ON] else None
    return {
        "thrust_scale": list(pp.k_thrust / k_eta),  # each rotor's thrust / (k_eta ω²)
        "torque_scale": list(pp.k_yaw / np.mean(pp.k_yaw)),  # each rotor's drag torque / (k_m ω²)
        "linear_drag": list(P[ps.P_LIN]),  # N s/m
        "quadratic_drag": list(P[ps.P_QUAD]),  # N s²/m²
        "rotor_drag": P[ps.P_RDRAG] / pp.unit,  # N s/m per rad/s
        "blade_flapping": P[ps.P_FLAP],  # N m s/m
        "rotor_drag_moment": P[ps.P_RDM] / pp.unit,  # N s/m per rad/s, at the hubs
        "translational_lift": P[ps.P_TLIFT],  # N s²/m² per rotor, at the hubs
        "wind_force": list(P[ps.P_WIND]),  # N, world
        "body_force_bias": list(P[ps.P_BBIAS]),  # N
        "torque_bias": list(P[ps.P_TBIAS]),  # N m
        "ground_effect": P[ps.P_GE],  # m²
        "ground_z": P[ps.P_GZ],  # m
        "marker_offset": list(P[ps.P_MARKER]),  # m, tracked point from the CG, body
        "remainder_hover_speed": P[ps.P_UHOVER] * pp.unit,  # rad/s
        "torque_remainder": None if rem is None else [list(r) for r in rem],  # N m per feature
        "residual": learned.residual_spec(vehicle, pp, file_stem(vehicle)),  # the learned body wrench (qr.residual)
    }


def _literal(x) -> str:
    return learned.literal(x, g)


MODULE = '''"""{name} for RotorPy 3: written by `qr export {path} --to rotorpy` (qr {version}).

    from {module} import quad_params, QrMultirotor
    vehicle = QrMultirotor()                    # qr's model, exactly (see mapping.md)
    vehicle = Multirotor(quad_params)           # RotorPy's own physics with the mapped coefficients

Body frame x forward, y left, z up; rotor speeds in rad/s; SI units.  mapping.md beside this file
states every conversion and approximation.  A learned wrench (QR_TERMS['residual']) is evaluated here
in NumPy from its weights beside this file (no torch, no qr needed).
"""
import os

import numpy as np
from scipy.spatial.transform import Rotation
from rotorpy.vehicles.multirotor import Multirotor

quad_params = {{
{params}
}}

# Terms RotorPy has no key for (QrMultirotor adds them); SI units, rad/s, body frame unless "world".
QR_TERMS = {{
{terms}
}}

MIN_GROUND_HEIGHT = {min_h}  # m, as qr's plant: keeps k T / h^2 finite in a crash
RESIDUAL = QR_TERMS["residual"]
REMAINDER = None if QR_TERMS["torque_remainder"] is None else np.asarray(QR_TERMS["torque_remainder"], float)
REMAINDER_HOVER_SPEED = QR_TERMS["remainder_hover_speed"]

{network}

def hover_state(position=(0.0, 0.0, 1.0)):
    """A state at rest, level, every rotor at the hover speed ({hover} rad/s)."""
    return {{"x": np.array(position, float), "v": np.zeros(3), "q": np.array([0.0, 0.0, 0.0, 1.0]),
            "w": np.zeros(3), "wind": np.zeros(3), "rotor_speeds": np.full({n}, {hover})}}


def tracked_point(state):
    """World position of the point a motion-capture system tracked (qr's marker_offset from the CG)."""
    R = Rotation.from_quat(state["q"]).as_matrix()
    return state["x"] + R @ QR_TERMS["marker_offset"]


class QrMultirotor(Multirotor):
    """RotorPy's Multirotor plus the terms of qr's model it has no key for (the learned ones included).

    exact_aero=True (default): RotorPy's own aerodynamics are switched off (aero=False) and qr's exact
    drag, flapping, rotor-drag moment and translational lift terms are added instead, so the vehicle
    integrates qr's plant.
    exact_aero=False: RotorPy's aerodynamics with the mapped keys (k_d, k_h, k_flap, c_D: approximate where
    mapping.md says), plus the terms it has no key for (a learned wrench then adds to RotorPy's
    aerodynamics, not to the qr model it was trained on)."""

    def __init__(self, params=None, initial_state=None, exact_aero=True, **kwargs):
        self.exact_aero = exact_aero
        if exact_aero:
            kwargs["aero"] = False
        super().__init__(quad_params if params is None else params,
                         hover_state() if initial_state is None else initial_state, **kwargs)
        self._scale = np.asarray(QR_TERMS["thrust_scale"], float)
        self._torque_scale = np.asarray(QR_TERMS["torque_scale"], float)

    def qr_wrench(self, s):
        """(world force, body force, body moment) qr's model adds to RotorPy's at the packed state s."""
        t = QR_TERMS
        R = Rotation.from_quat(s[6:10]).as_matrix()
        vb = R.T @ (s[3:6] - s[13:16])
        w, speeds = s[10:13], s[16:]
        thrust = self.k_eta * speeds**2  # RotorPy's own thrust of each rotor
        extra = (self._scale - 1.0) * thrust
        F = np.array([0.0, 0.0, extra.sum()])
        M = np.cross(self.rotor_geometry, np.outer(extra, [0.0, 0.0, 1.0])).sum(axis=0)
        M[2] += np.sum((self._torque_scale - 1.0) * self.rotor_dir * self.k_m * speeds**2)
        if self.exact_aero:
            F -= t["linear_drag"] * vb + t["quadratic_drag"] * np.abs(vb) * vb
            F[:2] -= t["rotor_drag"] * speeds.sum() * vb[:2]
            M += t["blade_flapping"] * np.array([vb[1], -vb[0], 0.0])
            if t["rotor_drag_moment"] or t["translational_lift"]:  # at each hub, with its airspeed v_b + w x r_i
                r = self.rotor_geometry
                wh = vb + np.cross(w, r)
                lift = t["translational_lift"] * (wh[:, 0]**2 + wh[:, 1]**2)
                H = -t["rotor_drag_moment"] * speeds[:, None] * wh * np.array([1.0, 1.0, 0.0])
                M += np.cross(r, H + np.outer(lift, [0.0, 0.0, 1.0])).sum(axis=0)
                F[2] += lift.sum()
        F += t["body_force_bias"]
        M += t["torque_bias"]
        if t["ground_effect"]:
            h = max(s[2] + R[2] @ t["marker_offset"] - t["ground_z"], MIN_GROUND_HEIGHT)
            F[2] += t["ground_effect"] * (self._scale * thrust).sum() / h**2
        f_learned, m_learned = learned_wrench(vb, w, -R[2], speeds)  # g_b = R^T [0, 0, -1]
        F += f_learned
        M += m_learned
        return np.asarray(t["wind_force"], float), F, M

    def _s_dot_fn(self, t, s, cmd_rotor_speeds):
        s_dot = super()._s_dot_fn(t, s, cmd_rotor_speeds)
        F_world, F_body, M_body = self.qr_wrench(s)
        R = Rotation.from_quat(s[6:10]).as_matrix()
        s_dot[3:6] += (R @ F_body + F_world) / self.mass
        s_dot[10:13] += self.inv_inertia @ M_body
        return s_dot
'''


def module_text(vehicle, pp: mp.Plant, path: str, version: str, module: str) -> str:
    params = quad_params(pp)
    lines = []
    for k, v in params.items():
        if k == "rotor_pos":
            inner = ",\n".join(f"        '{r}': {_literal(p)}" for r, p in v.items())
            lines.append(f"    'rotor_pos': {{\n{inner},\n    }},")
        else:
            lines.append(f"    '{k}': {_literal(v)},")
    terms = "\n".join(f"    '{k}': {_literal(v)}," for k, v in qr_terms(vehicle, pp).items())
    return MODULE.format(name=vehicle.name, path=path, version=version, module=module, params="\n".join(lines),
                         terms=terms, min_h=g(pl.MIN_GROUND_HEIGHT), hover=g(pp.hover), n=len(pp.yaw_signs),
                         network=learned.LEARNED_SOURCE)


def rows(vehicle, pp: mp.Plant) -> list[Row]:
    """The mapping of every key, parameter and named effect of the vehicle file onto RotorPy."""
    qp, size = quad_params(pp), mp.sizes(pp)
    effect_rows = (_rotor_effect_row(name, vehicle, pp, qp, size) or _body_effect_row(name, vehicle, pp, qp, size)
                   for name in mp.present(vehicle))
    return [*_key_rows(vehicle, pp, qp), *(r for r in effect_rows if r is not None), *_imbalance_torque(vehicle, pp),
            *_learned_rows(vehicle, pp, size)]


def _imbalance_torque(vehicle, pp: mp.Plant) -> list[Row]:
    """motor_imbalance's drag-torque part: each rotor's relative to the others' (their mean stays k_m)."""
    if not mp.has(vehicle, "motor_imbalance"):
        return []
    return [Row("motor_imbalance (drag torque)", "d_i", "QR_TERMS['torque_scale']",
                _vec(qr_terms(vehicle, pp)["torque_scale"]), EXACT,
                "QrMultirotor adds each rotor's (torque_scale_i - 1) rotor_directions_i k_m ω_i² about body z; the "
                "mean drag torque stays k_m's", formula=f"1 + d_i − {mp.fx_d_mean(vehicle)}")]


def _key_rows(vehicle, pp: mp.Plant, qp: dict) -> list[Row]:
    """The vehicle file's keys (mass, inertia, coefficients, layout, motors, ground) and RotorPy's own settings."""
    u = vehicle.rotor_speed_unit
    rx, ry = mp.fx_cg(vehicle)
    lift = mp.has(vehicle, "translational_lift")  # named: its row maps k_h
    out = mp.common_rows(vehicle, pp, {
        "name": (f"module {file_stem(vehicle)}_params", file_stem(vehicle), ""),
        "mass": ("mass", g(qp["mass"]) + " kg", mp.fx_mass(vehicle)),
        "inertia": ("Ixx, Iyy, Izz (Ixy = Iyz = Ixz = 0)", ", ".join(g(qp[k]) for k in ("Ixx", "Iyy", "Izz")),
                    ", ".join(mp.fx_inertia(vehicle))),
        "thrust_coeff": ("k_eta", g(qp["k_eta"]) + " N/(rad/s)²", mp.fx_k_thrust(vehicle, mean=True),
                         "the rotors' mean thrust per (rad/s)²" + ("; each rotor's part: motor_imbalance row"
                                                                    if mp.has(vehicle, "motor_imbalance") else "")),
        "torque_coeff": ("k_m", g(qp["k_m"]) + " N m/(rad/s)²", mp.fx_k_yaw(vehicle, mean=True),
                         "the rotors' drag torque per (rad/s)²" + ("; each rotor's part: motor_imbalance row"
                                                                    if mp.has(vehicle, "motor_imbalance") else "")),
    })
    out += [
        Row("layout (rotor x, y), hub_z", ", ".join(f"({g(x)}, {g(y)})" for x, y in vehicle.rotors.positions)
            + f"; {g(pp.hub_z)} m", "rotor_pos", ", ".join(f"({g(r[0])}, {g(r[1])}, {g(r[2])})" for r in pp.rotor_pos),
            EXACT, "m, relative to the CG (cg_offset subtracted); the hubs hub_z above it",
            formula=f"({mp.fx_minus('x_i', rx)}, {mp.fx_minus('y_i', ry)}, hub_z)"),
        Row("layout (yaw_sign)", ", ".join(f"{s:+g}" for s in vehicle.rotors.yaw_signs), "rotor_directions",
            ", ".join(f"{s:+g}" for s in pp.yaw_signs), EXACT,
            "RotorPy's moment is rotor_directions_i k_m ω_i² about body z: the reaction torque's sign, as yaw_sign",
            formula="s_i"),
        Row("motor_time_constant", g(vehicle.motor_time_constant) + " s", "tau_m", g(qp["tau_m"]) + " s", EXACT,
            "first-order lag in both", formula="τ_m"),
        Row("rotor_speed_min, rotor_speed_max", f"{g(vehicle.rotor_speed_min)}, {g(vehicle.rotor_speed_max)} {u}",
            "rotor_speed_min, rotor_speed_max", f"{g(qp['rotor_speed_min'])}, {g(qp['rotor_speed_max'])} rad/s", EXACT,
            "× f", formula="f · u_min, f · u_max"),
        mp.ground_row(vehicle, "QR_TERMS['ground_z']", g(pp.P[ps.P_GZ]) + " m"),
        Row("(none: no vertical rotor drag in qr" + ("" if lift else ", no translational_lift named") + ")",
            "-", "k_z" + ("" if lift else ", k_h"), "0" + ("" if lift else ", 0"), EXACT,
            "RotorPy's defaults for other vehicles are not carried over", formula="0" + ("" if lift else ", 0")),
        Row("(none)", "-", "motor_noise_std, rI", "0, [0, 0, 0]", EXACT, "no noise; IMU at the CG",
            formula="0, 0, 0, 0"),
        Row("(none: qr has no propeller size)", "-", "rotor_radius", g(qp["rotor_radius"]) + " m", EXACT,
            "drawing only in RotorPy: half the smallest distance between two rotor axes"),
        Row("(RotorPy's low-level gains)", "-", "k_w, k_v, kp_att, kd_att",
            ", ".join(g(DEFAULT_GAINS[k]) for k in ("k_w", "k_v", "kp_att", "kd_att")), EXACT,
            "RotorPy's own defaults (used only by its cmd_ctbr/cmd_vel/cmd_acc/cmd_ctatt abstractions; not qr's)",
            formula=", ".join(g(DEFAULT_GAINS[k]) for k in ("k_w", "k_v", "kp_att", "kd_att"))),
    ]
    return out


def _rotor_effect_row(name: str, vehicle, pp: mp.Plant, qp: dict, size: dict) -> Row | None:
    """The row of a named effect that acts through the rotors (their coefficients, positions, drag, lift)."""
    P, val, n = pp.P, mp.effect_value(vehicle, name), len(pp.yaw_signs)
    if name == "thrust_gain":
        return Row(name, val, "k_eta", g(qp["k_eta"]), EXACT, "k_eta = gain C_T / f²",
                   formula=mp.fx_k_thrust(vehicle, mean=True))
    elif name == "yaw_torque_gain":
        return Row(name, val, "k_m", g(qp["k_m"]), EXACT, "k_m = gain C_Q / f²",
                   formula=mp.fx_k_yaw(vehicle, mean=True))
    elif name == "cg_offset":
        return Row(name, val, "rotor_pos", "(shifted)", EXACT,
                   "rotor_pos_i = (x_i - rx, y_i - ry, hub_z): thrust moment Γ - c × T = the catalog's [-ry T, rx T, 0]")
    elif name == "motor_imbalance":
        ds = " + ".join(f"d_{i}" for i in range(1, n + 1))
        return Row(name, val, "k_eta (mean) + QR_TERMS['thrust_scale']",
                   _vec(qr_terms(vehicle, pp)["thrust_scale"]), EXACT,
                   "QrMultirotor adds each rotor's (thrust_scale_i - 1) k_eta ω_i² at its hub; Multirotor(quad_params) "
                   "alone has their mean k_eta", formula=f"n · (1 + d_i) / (n + {ds})")
    elif name == "rotor_drag":
        both = P[ps.P_RDM] == P[ps.P_RDRAG]  # named with its moment (one k): RotorPy's H-force at the hubs is both
        return Row(name, val, "k_d (rotor_drag_matrix = diag(k_d, k_d, k_z))",
                   g(qp["k_d"]) + " N s/m per rad/s", APPROXIMATE,
                   "k_d = k / f; RotorPy applies -k_d ω_i [w_x, w_y] at each hub with its airspeed w = v + ω × r_i: "
                   "its force has -k_d Σ ω_i (ω × r_i)_xy more than qr's -k Σu [v_x, v_y] (zero at equal rotor "
                   "speeds with no roll/pitch rate or the hubs in the CG's plane)"
                   + ("; its moment about the CG is rotor_drag_moment's (named, the same k)" if both else
                      "; its moment about the CG, a yaw-rate damping -k_d Σ ω_i (r_ix² + r_iy²) ω_z and more, is "
                      "RotorPy's addition (qr's rotor_drag_moment, not named)")
                   + ". QrMultirotor (exact_aero) applies qr's terms exactly", formula="rotor_drag.k / f")
    elif name == "rotor_drag_moment":
        same = P[ps.P_RDM] == P[ps.P_RDRAG]
        return Row(name, val, "k_d (rotor_drag_matrix), rotor_pos", g(qp["k_d"]) + " N s/m per rad/s",
                   EXACT if same else IMPOSSIBLE if not P[ps.P_RDRAG] else APPROXIMATE,
                   "k_d = k / f, the same as rotor_drag's: RotorPy's rotor drag at the hubs has the moment "
                   "Σ r_i × (-k_d ω_i [w_ix, w_iy, 0]) about the CG, qr's term exactly" if same else
                   f"RotorPy's rotor drag is a force at the hubs, its moment comes with it: k_d carries rotor_drag's "
                   f"k ({g(qp['k_d'])} per rad/s), {mp.untied_moment(P)} "
                   f"({size[name]}). QrMultirotor (exact_aero) applies qr's term exactly",
                   formula="rotor_drag.k / f" if mp.has(vehicle, "rotor_drag") else "0")
    elif name == "translational_lift":
        return Row(name, val, "k_h", g(qp["k_h"]) + " N/(m/s)² per rotor", EXACT,
                   "k_h = k: RotorPy's thrust k_eta ω_i² + k_h (w_ix² + w_iy²) with the hub airspeed w = v + ω × r_i, "
                   "qr's term", formula="translational_lift.k")
    elif name == "blade_flapping":
        return Row(name, val, "k_flap", g(qp["k_flap"]) + " N m s/m per rad/s", APPROXIMATE,
                   f"k_flap = -k / (4 ω_hover), ω_hover = {g(pp.hover)} rad/s: RotorPy's moment -k_flap Σω_i "
                   "[v_iy, -v_ix, 0] grows with the rotor speeds, qr's k [v_y, -v_x, 0] does not: exact at "
                   "equal rotor speeds summing to 4 ω_hover (CG at the rotors' centre); relative error "
                   "|Σω/(4 ω_hover) - 1| of the moment otherwise. QrMultirotor (exact_aero) applies qr's term exactly",
                   formula="−blade_flapping.k / (n · ω_h)")
    return None


def _body_effect_row(name: str, vehicle, pp: mp.Plant, qp: dict, size: dict) -> Row | None:
    """The row of a named effect on the body (mass and inertia errors, drag, forces, the ground, the marker, the
    delay)."""
    P, val = pp.P, mp.effect_value(vehicle, name)
    if name in ("mass_error", "inertia_error"):
        return Row(name, val, "mass" if name == "mass_error" else "Ixx, Iyy, Izz", "(added)", EXACT,
                   "added to the vehicle's value (mass, inertia rows)")
    elif name == "quadratic_drag":
        return Row(name, val, "c_Dx, c_Dy, c_Dz", ", ".join(g(qp[k]) for k in ("c_Dx", "c_Dy", "c_Dz")),
                   APPROXIMATE, "c_Dj = c_j: RotorPy's -c_Dj |v| v_j equals qr's -c_j |v_j| v_j for airspeed "
                   "along one body axis, and is larger by |v|/|v_j| otherwise. QrMultirotor (exact_aero) "
                   "applies qr's term exactly", formula=", ".join(mp.fx_effect(vehicle, name, ("cx", "cy", "cz"))))
    elif name == "linear_drag":
        return Row(name, val, "QR_TERMS['linear_drag']", _vec(P[ps.P_LIN]) + " N s/m",
                   EXACT, "RotorPy has no constant linear drag (k_d, k_z scale with the rotor speed): "
                   f"QrMultirotor adds -diag(k) v_b ({size['linear_drag']})",
                   formula=", ".join(mp.fx_effect(vehicle, name, ("kx", "ky", "kz"))))
    elif name in ("wind_force", "body_force_bias", "torque_bias"):
        unit = {"wind_force": "N, world", "body_force_bias": "N, body", "torque_bias": "N m, body"}[name]
        off = {"wind_force": ps.P_WIND, "body_force_bias": ps.P_BBIAS, "torque_bias": ps.P_TBIAS}[name]
        params = {"wind_force": ("fx", "fy", "fz"), "body_force_bias": ("bx", "by", "bz"),
                  "torque_bias": ("tx", "ty", "tz")}[name]
        return Row(name, val, f"QR_TERMS['{name}']", _vec(P[off]) + " " + unit, EXACT,
                   f"no RotorPy key: QrMultirotor adds it ({size[name]})",
                   formula=", ".join(mp.fx_effect(vehicle, name, params)))
    elif name == "ground_effect":
        return Row(name, val, "QR_TERMS['ground_effect']", f"{g(P[ps.P_GE])} m²", EXACT,
                   f"no RotorPy key: QrMultirotor adds k T / h² along body z, h above ground_z ({size[name]})",
                   formula="ground_effect.k")
    elif name == "marker_offset":
        return Row(name, val, "QR_TERMS['marker_offset']", _vec(P[ps.P_MARKER]) + " m",
                   EXACT, "not a force: RotorPy's state is the CG; tracked_point(state) gives the tracked "
                   f"point x + R r ({size[name]}), and the ground effect's height uses it",
                   formula=", ".join(mp.fx_effect(vehicle, name, ("rx", "ry", "rz"))))
    elif name == "actuator_delay":
        return Row(name, val, "-", "-", IMPOSSIBLE,
                   f"RotorPy's wrench follows the rotor speeds at once ({size[name]}): not exported; with its "
                   "first-order motors, delaying cmd_motor_speeds by the same time is equivalent")
    return None


def _learned_rows(vehicle, pp: mp.Plant, size: dict) -> list[Row]:
    """The learned terms: a torque remainder, a residual network."""
    out = []
    if pp.P[ps.P_REM_ON]:
        out.append(Row("torque_remainder", "W (3 × 11)", "QR_TERMS['torque_remainder']", "the file's W", EXACT,
                       f"a learned map, no RotorPy key: QrMultirotor adds W φ ({size['torque_remainder']})"))
    if vehicle.residual is not None:
        out.append(Row("residual", mp.residual_item(vehicle), f"QR_TERMS['residual'], {residual_file(vehicle)}",
                       "the file's network", EXACT,
                       "no RotorPy key: QrMultirotor adds the network's body force and torque at the CG at every "
                       "evaluation of the dynamics (residual_wrench: NumPy, rotor speeds ÷ f into qr's scaling; "
                       f"weights copied beside the module); its size: {mp.residual_size(vehicle, pp)}"))
    return out


def files(vehicle, pp: mp.Plant, path: str, version: str) -> list[File]:
    """``<name>_params.py`` and, for a hybrid, the learned wrench's weights beside it."""
    module = file_stem(vehicle) + "_params"
    return [File(f"{module}.py", module_text(vehicle, pp, path, version, module)),
            *learned.weights(vehicle, file_stem(vehicle))]


INTRO = ["`QrMultirotor` (the module's subclass of RotorPy's `Multirotor`, `exact_aero=True` by default) switches "
         "RotorPy's own aerodynamics off and adds qr's terms exactly, a learned torque remainder and a learned wrench "
         "(`residual_wrench`, the network in NumPy) included: it integrates qr's plant, and every row "
         "below holds for it except those marked impossible. `Multirotor(quad_params)` alone has RotorPy's own "
         "physics with the mapped keys: the rows marked approximate hold under their condition, the terms under "
         "`QR_TERMS` are missing. f = rad/s per rotor-speed unit."]
