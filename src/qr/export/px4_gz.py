"""``qr export --to px4-gz``: a Gazebo Sim model folder for PX4 SITL, and the PX4 parameters that agree with it.

Element names follow the stock PX4 x500 model; the ``MulticopterMotorModel`` plugin's equations against qr's
plant (``motorConstant``, ``momentConstant``, ``turningDirection``, ``rotorDragCoefficient``, why flapping is
impossible, ``CA_ROTOR<i>_*``): docs/export.md "How each convention was derived".
"""

from __future__ import annotations

from xml.sax.saxutils import escape

import numpy as np

from .. import plant_state as ps
from . import mapping as mp
from .mapping import APPROXIMATE, EXACT, IMPOSSIBLE, File, Row, file_stem, g

ROTOR_MASS_FRACTION = 0.0025  # of the vehicle's mass, per rotor link (Gazebo needs a mass on every link)
SLOWDOWN = 10  # rotorVelocitySlowdownSim, as the x500 (the joint turns 10x slower than the real rotor)
PLUGIN = ("gz-sim-multicopter-motor-model-system", "gz::sim::systems::MulticopterMotorModel")
PARAM_REAL32, PARAM_INT32 = 9, 6  # QGroundControl parameter file types


def turning(yaw_sign: float) -> str:
    return "ccw" if yaw_sign < 0 else "cw"


def rotor_link_inertia(pp: mp.Plant) -> tuple[float, np.ndarray]:
    """Mass (kg) and principal inertia (kg m²) of a rotor link: a thin rod of the arm's half length."""
    m_r = ROTOR_MASS_FRACTION * pp.mass
    L = pp.arm / 2
    i_rod = m_r * L**2 / 12
    return m_r, np.array([m_r * 1e-4 * L**2, i_rod, i_rod])


def base_link(pp: mp.Plant) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, CoM (body, 3) and inertia tensor (3 x 3, about its CoM) of base_link such that base_link and
    the rotor links together have the vehicle's mass, its CG and its principal inertia about the CG."""
    m_r, j_r = rotor_link_inertia(pp)
    n = len(pp.yaw_signs)
    m_b = pp.mass - n * m_r
    c = np.array([pp.cg[0], pp.cg[1], 0.0])
    r = np.zeros((n, 3))
    r[:, :2] = pp.rotor_xy
    c_b = (pp.mass * c - m_r * r.sum(axis=0)) / m_b
    J = np.diag(pp.inertia).astype(float)

    def shift(m, d):  # parallel-axis term
        return m * (d @ d * np.eye(3) - np.outer(d, d))

    J_b = J - sum(np.diag(j_r) + shift(m_r, ri - c) for ri in r) - shift(m_b, c_b - c)
    return m_b, c_b, J_b


def _inertia_xml(J: np.ndarray, indent: str) -> list[str]:
    names = (("ixx", 0, 0), ("ixy", 0, 1), ("ixz", 0, 2), ("iyy", 1, 1), ("iyz", 1, 2), ("izz", 2, 2))
    return [f"{indent}<{k}>{g(J[i, j])}</{k}>" for k, i, j in names]


def model_sdf(vehicle, pp: mp.Plant, path: str, version: str, model: str) -> str:
    m_b, c_b, J_b = base_link(pp)
    m_r, j_r = rotor_link_inertia(pp)
    L = ['<?xml version="1.0" encoding="UTF-8"?>',
         f"<!-- {vehicle.name.replace('--', '- -')}: written by qr {version} (qr export, for px4-gz); see ../mapping.md -->",
         "<sdf version='1.9'>", f"  <model name='{model}'>", "    <self_collide>false</self_collide>",
         "    <static>false</static>", '    <link name="base_link">', "      <inertial>",
         f"        <pose>{g(c_b[0])} {g(c_b[1])} {g(c_b[2])} 0 0 0</pose>", f"        <mass>{g(m_b)}</mass>",
         "        <inertia>", *_inertia_xml(J_b, "          "), "        </inertia>", "      </inertial>",
         "      <gravity>true</gravity>", "      <velocity_decay/>",
         '      <sensor name="air_pressure_sensor" type="air_pressure">',
         "        <always_on>1</always_on>", "        <update_rate>50</update_rate>", "      </sensor>",
         '      <sensor name="imu_sensor" type="imu">', "        <always_on>1</always_on>",
         "        <update_rate>250</update_rate>", "      </sensor>",
         '      <sensor name="navsat_sensor" type="navsat">', "        <always_on>1</always_on>",
         "        <update_rate>30</update_rate>", "      </sensor>", "    </link>"]
    for i, (x, y) in enumerate(pp.rotor_xy):
        L += [f'    <link name="rotor_{i}">', "      <gravity>true</gravity>", "      <self_collide>false</self_collide>",
              "      <velocity_decay/>", f"      <pose>{g(x)} {g(y)} 0 0 0 0</pose>", "      <inertial>",
              f"        <mass>{g(m_r)}</mass>", "        <inertia>",
              *_inertia_xml(np.diag(j_r), "          "), "        </inertia>", "      </inertial>", "    </link>",
              f'    <joint name="rotor_{i}_joint" type="revolute">', "      <parent>base_link</parent>",
              f"      <child>rotor_{i}</child>", "      <axis>", "        <xyz>0 0 1</xyz>", "        <limit>",
              "          <lower>-1e+16</lower>", "          <upper>1e+16</upper>", "        </limit>",
              "      </axis>", "    </joint>"]
    for i, p in enumerate(plugin_values(pp)):
        L += [f'    <plugin filename="{PLUGIN[0]}"', f'      name="{PLUGIN[1]}">',
              *(f"      <{k}>{v}</{k}>" for k, v in p.items()), "    </plugin>"]
    L += ["  </model>", "</sdf>"]
    return "\n".join(L) + "\n"


def plugin_values(pp: mp.Plant) -> list[dict]:
    """The MulticopterMotorModel elements of each rotor, in the x500's order."""
    P = pp.P
    out = []
    for i, (k, kq, s) in enumerate(zip(pp.k_thrust, pp.k_yaw, pp.yaw_signs)):
        out.append({"jointName": f"rotor_{i}_joint", "linkName": f"rotor_{i}", "turningDirection": turning(s),
                    "timeConstantUp": g(pp.tau_m), "timeConstantDown": g(pp.tau_m),
                    "maxRotVelocity": g(pp.speed_max), "motorConstant": g(k), "momentConstant": g(kq / k),
                    "commandSubTopic": "command/motor_speed", "motorNumber": str(i),
                    "rotorDragCoefficient": g(P[ps.P_RDRAG] / pp.unit), "rollingMomentCoefficient": "0",
                    "rotorVelocitySlowdownSim": str(SLOWDOWN), "motorType": "velocity"})
    return out


def px4_params(pp: mp.Plant) -> list[tuple[str, float | int, int]]:
    """(name, value, type) of the PX4 parameters that must agree with the model."""
    out: list[tuple[str, float | int, int]] = [("CA_ROTOR_COUNT", len(pp.yaw_signs), PARAM_INT32)]
    for i, ((x, y), k, kq, s) in enumerate(zip(pp.rotor_xy, pp.k_thrust, pp.k_yaw, pp.yaw_signs)):
        out += [(f"CA_ROTOR{i}_PX", x - pp.cg[0], PARAM_REAL32), (f"CA_ROTOR{i}_PY", -(y - pp.cg[1]), PARAM_REAL32),
                (f"CA_ROTOR{i}_PZ", 0.0, PARAM_REAL32), (f"CA_ROTOR{i}_KM", -s * kq / k, PARAM_REAL32)]
    for i in range(len(pp.yaw_signs)):
        out += [(f"SIM_GZ_EC_FUNC{i + 1}", 101 + i, PARAM_INT32),
                (f"SIM_GZ_EC_MIN{i + 1}", int(round(pp.speed_min)), PARAM_INT32),
                (f"SIM_GZ_EC_MAX{i + 1}", int(round(pp.speed_max)), PARAM_INT32)]
    return out


def params_text(vehicle, pp: mp.Plant, path: str, version: str) -> str:
    """A QGroundControl parameter file (vehicle id, component id, name, value, type; tab-separated)."""
    lines = [f"# {vehicle.name}: written by qr export {path} --to px4-gz (qr {version}); see mapping.md",
             "# Vehicle-Id\tComponent-Id\tName\tValue\tType"]
    for name, val, typ in px4_params(pp):
        lines.append(f"1\t1\t{name}\t{g(val) if typ == PARAM_REAL32 else int(val)}\t{typ}")
    return "\n".join(lines) + "\n"


def model_config(vehicle, model: str, version: str) -> str:
    return "\n".join(['<?xml version="1.0"?>', "<model>", f"  <name>{model}</name>", "  <version>1.0</version>",
                      "  <sdf version='1.9'>model.sdf</sdf>", "  <author>", "    <name>qr export</name>",
                      "  </author>", f"  <description>{escape(vehicle.name)}, exported by qr {version} (see ../mapping.md)"
                      "</description>", "</model>"]) + "\n"


def rows(vehicle, pp: mp.Plant) -> list[Row]:
    """The mapping of every key, parameter and named effect of the vehicle file onto the Gazebo model and PX4."""
    plug, size = plugin_values(pp), mp.sizes(pp)
    effect_rows = (_effect_row(name, vehicle, pp, plug, size) for name in mp.present(vehicle))
    return [*_key_rows(vehicle, pp, plug), *(r for r in effect_rows if r is not None),
            *_learned_rows(vehicle, pp, size)]


def _moment_formula(vehicle) -> str:
    """momentConstant = k_yaw_i / k_i: C_Q / C_T with the gains and the imbalance of rotor i (f² cancels)."""
    k_i = mp.fx_k_thrust(vehicle).removesuffix(" / f²")
    q = mp.fx_k_yaw(vehicle).removesuffix(" / f²")
    return f"{q} / ({k_i})" if k_i != "C_T" else f"{q} / C_T"


def _key_rows(vehicle, pp: mp.Plant, plug: list[dict]) -> list[Row]:
    """The vehicle file's keys (mass, inertia, coefficients, layout, motors, ground) on the model and PX4."""
    m_b, _, _ = base_link(pp)
    m_r, _ = rotor_link_inertia(pp)
    frac = g(ROTOR_MASS_FRACTION)
    mass = mp.fx_mass(vehicle) if not mp.has(vehicle, "mass_error") else f"({mp.fx_mass(vehicle)})"
    rx, ry = mp.fx_cg(vehicle)
    moment = _moment_formula(vehicle)
    out = mp.common_rows(vehicle, pp, {
        "name": ("model name (model.config, model.sdf), folder", file_stem(vehicle), ""),
        "mass": ("base_link, rotor_<i> inertial/mass", f"{g(m_b)} (base_link), {g(m_r)} (each rotor link) kg",
                 f"{mass} · (1 − n · {frac}), {mass} · {frac}",
                 f"kg: rotor links {100 * ROTOR_MASS_FRACTION:g} % of the mass each (Gazebo needs a mass on every "
                 "link), base_link the rest" + ("; mass_error added" if mp.has(vehicle, "mass_error") else "")),
        "inertia": ("base_link inertial/inertia (+ rotor links)", "(composed, see note)", "",
                    "base_link's tensor = J - rotor links' (own + parallel-axis) - base's own shift to the CG: the "
                    "composite has the vehicle's principal inertia about the CG"
                    + ("; inertia_error added" if mp.has(vehicle, "inertia_error") else "")),
        "thrust_coeff": ("motorConstant", ", ".join(p["motorConstant"] for p in plug) + " N/(rad/s)²",
                         mp.fx_k_thrust(vehicle), f"C_T per {vehicle.rotor_speed_unit}² → per (rad/s)²: ÷ f²"),
        "torque_coeff": ("momentConstant", ", ".join(p["momentConstant"] for p in plug) + " m", moment,
                         "gz's drag torque is momentConstant × thrust: C_Q / C_T, a length (the f² cancels)"),
    })
    return out + [
        Row("layout (yaw_sign)", ", ".join(f"{s:+g}" for s in vehicle.rotors.yaw_signs), "turningDirection",
            ", ".join(p["turningDirection"] for p in plug), EXACT,
            "gz drag torque = -turningDirection (ccw +1) momentConstant thrust: yaw_sign -1 ↔ ccw"),
        Row("layout (rotor x, y)", ", ".join(f"({g(x)}, {g(y)})" for x, y in pp.rotor_xy), "rotor_<i> pose",
            ", ".join(f"({g(x)}, {g(y)}, 0)" for x, y in pp.rotor_xy), EXACT, "links at (x, y, 0) in base_link",
            formula="(x_i, y_i, 0)"),
        Row("layout (rotor x, y) for PX4", "(relative to the CG)", "CA_ROTOR<i>_PX, CA_ROTOR<i>_PY",
            ", ".join(f"({g(x - pp.cg[0])}, {g(-(y - pp.cg[1]))})" for x, y in pp.rotor_xy), EXACT,
            "PX4 in FRD relative to the CG: PX = x - rx, PY = -(y - ry)",
            formula=f"({mp.fx_minus('x_i', rx)}, −({mp.fx_minus('y_i', ry)}))"),
        Row("torque_coeff sign", "yaw_sign", "CA_ROTOR<i>_KM", ", ".join(g(-s * kq / k) for k, kq, s in
            zip(pp.k_thrust, pp.k_yaw, pp.yaw_signs)), EXACT, "PX4's moment CT p × a - CT KM a, a = (0, 0, -1) FRD: "
            "KM = -yaw_sign C_Q / C_T (positive for ccw, as PX4 documents)", formula=f"−s_i · {moment}"),
        Row("motor_time_constant", g(vehicle.motor_time_constant) + " s", "timeConstantUp, timeConstantDown",
            f"{g(pp.tau_m)}, {g(pp.tau_m)} s", EXACT, "qr's lag is the same up and down", formula="τ_m, τ_m"),
        Row("rotor_speed_max", f"{g(vehicle.rotor_speed_max)} {vehicle.rotor_speed_unit}",
            "maxRotVelocity; SIM_GZ_EC_MAX<i>", f"{g(pp.speed_max)}; {int(round(pp.speed_max))} rad/s", EXACT,
            "× f (PX4's parameter is an integer: rounded)", formula="f · u_max, round(f · u_max)"),
        Row("rotor_speed_min", f"{g(vehicle.rotor_speed_min)} {vehicle.rotor_speed_unit}", "SIM_GZ_EC_MIN<i>",
            f"{int(round(pp.speed_min))} rad/s", EXACT, "× f, rounded (PX4 maps its output range onto [MIN, MAX])",
            formula="round(f · u_min)"),
        Row("(none)", "-", "rollingMomentCoefficient", "0", EXACT,
            "gz's rolling moment is a torque about v⊥; qr has no such term (flapping acts about v × e_z)", formula="0"),
        mp.ground_row(vehicle),
        mp.hub_row(vehicle, "rotor_<i> pose (z)", kept=("rotor_drag_moment",) if pp.P[ps.P_RDRAG] else ()),
    ]


def _effect_row(name: str, vehicle, pp: mp.Plant, plug: list[dict], size: dict) -> Row | None:
    """The row of a named effect: on the motor model, the links, or left out (impossible) with its size."""
    P, val, n, frac = pp.P, mp.effect_value(vehicle, name), len(pp.yaw_signs), g(ROTOR_MASS_FRACTION)
    _, c_b, _ = base_link(pp)
    xs = " + ".join(f"x_{i}" for i in range(1, n + 1))
    ys = " + ".join(f"y_{i}" for i in range(1, n + 1))
    if name in ("mass_error", "inertia_error"):
        return Row(name, val, "inertial", "(added)", EXACT, "added to the vehicle's value (mass, inertia rows)")
    elif name in ("thrust_gain", "motor_imbalance"):
        return Row(name, val, "motorConstant (per rotor); momentConstant, CA_ROTOR<i>_KM",
                   ", ".join(p["motorConstant"] for p in plug), EXACT,
                   "motorConstant_i = gain (1 + d_i) C_T / f²; momentConstant_i = C_Q (1 + d_i − mean d) / (gain (1 + d_i) "
                   "C_T): gz's drag torque, momentConstant × thrust, is qr's", formula=mp.fx_k_thrust(vehicle))
    elif name == "yaw_torque_gain":
        return Row(name, val, "momentConstant; CA_ROTOR<i>_KM", ", ".join(p["momentConstant"] for p in plug),
                   EXACT, "gain C_Q / C_T", formula=_moment_formula(vehicle))
    elif name == "cg_offset":
        return Row(name, val, "base_link inertial/pose; CA_ROTOR<i>_PX/PY", f"{g(c_b[0])}, {g(c_b[1])}, 0",
                   EXACT, "base_link's CoM such that the composite CG is at (rx, ry): the thrusts' moment "
                   "Γ - c × T = [-ry T, rx T, 0]; PX4's rotor positions relative to it",
                   formula=f"(cg_offset.rx − {frac} · ({xs})) / (1 − n · {frac}), "
                           f"(cg_offset.ry − {frac} · ({ys})) / (1 − n · {frac}), 0")
    elif name == "rotor_drag":
        return Row(name, val, "rotorDragCoefficient", plug[0]["rotorDragCoefficient"] + " N s/m per rad/s",
                   APPROXIMATE, "k / f; gz applies -|ω_i| k v⊥ at each rotor link with the link's own "
                   "velocity (v + ω × r_i): its force is qr's at equal rotor speeds and zero body rate"
                   + ("; its moment about the CG is rotor_drag_moment's (named, the same k)"
                      if P[ps.P_RDM] == P[ps.P_RDRAG] else
                      "; its moment about the CG (a yaw-rate damping) is gz's addition (rotor_drag_moment, not named)"),
                   formula="rotor_drag.k / f")
    elif name == "rotor_drag_moment":
        same = P[ps.P_RDM] == P[ps.P_RDRAG]
        flat = pp.hub_z == 0
        return Row(name, val, "rotorDragCoefficient; rotor_<i> pose", plug[0]["rotorDragCoefficient"]
                   + " N s/m per rad/s", EXACT if same and flat else IMPOSSIBLE if not P[ps.P_RDRAG] else APPROXIMATE,
                   ("gz's rotor drag acts at each rotor link with the link's velocity: its moment about the CG is "
                    "qr's term with rotor_drag's k" + ("" if flat else
                                                       f"; the links sit in the CG's plane, not hub_z = {g(pp.hub_z)} m "
                                                       "above it: the roll/pitch part is left out")) if same else
                   f"gz's rotor drag is a force at the links, its moment comes with it: rotorDragCoefficient "
                   f"carries rotor_drag's k, {mp.untied_moment(P)} "
                   f"({size[name]})", formula="rotor_drag.k / f" if mp.has(vehicle, "rotor_drag") else "0")
    elif name == "blade_flapping":
        return Row(name, val, "-", "-", IMPOSSIBLE, f"torque about v × e_z ({size[name]}); gz's "
                   "rollingMomentCoefficient acts about v⊥ itself, a different axis: left at 0, flapping "
                   "left out")
    elif name == "marker_offset":
        return Row(name, val, "-", "-", IMPOSSIBLE, f"not a force ({size[name]}): the model's pose is "
                   "base_link; the tracked point is its pose plus R r")
    elif name in size:
        return Row(name, val, "-", "-", IMPOSSIBLE, f"no element of the motor model or the link "
                   f"({size[name]}): left out")
    return None


def _learned_rows(vehicle, pp: mp.Plant, size: dict) -> list[Row]:
    """The learned terms, which neither the Gazebo model nor PX4 can hold."""
    out = []
    if pp.P[ps.P_REM_ON]:
        out.append(Row("torque_remainder", "W (3 × 11)", "-", "-", IMPOSSIBLE,
                       f"a learned map ({size['torque_remainder']}): no element of the Gazebo model holds it: left "
                       "out, the model flies without it"))
    if vehicle.residual is not None:
        out.append(Row("residual", mp.residual_item(vehicle), "-", "-", IMPOSSIBLE,
                       "a learned body wrench: no element of the Gazebo model or of PX4 holds a network: left out, "
                       f"the model flies the physical part only. Its size: {mp.residual_size(vehicle, pp)}"))
    return out


def files(vehicle, pp: mp.Plant, path: str, version: str) -> list[File]:
    """The model folder ``<name>/`` (model.sdf, model.config) and the PX4 parameters ``<name>.params``."""
    model = file_stem(vehicle)
    return [File(f"{model}/model.sdf", model_sdf(vehicle, pp, path, version, model)),
            File(f"{model}/model.config", model_config(vehicle, model, version)),
            File(f"{model}.params", params_text(vehicle, pp, path, version))]


INTRO = ["The model folder goes on GZ_SIM_RESOURCE_PATH (PX4: Tools/simulation/gz/models/); the .params file "
         "is QGroundControl's parameter file format. Rotor i of the vehicle file is rotor_<i-1>, motorNumber "
         "i-1 and PX4's motor i (SIM_GZ_EC_FUNC<i> = 100 + i). f = rad/s per rotor-speed unit."]
