"""``qr export --to mujoco``: an MJCF model, ``<name>.xml``.

One free body whose frame is the vehicle file's body frame (x forward, z up, origin at the rotor
map's origin), its ``<inertial>`` at the CG (``cg_offset``) with the mass and principal inertia, one
site per rotor hub, and two actuators per rotor at its site: a thrust along the site's z with
``gear = k_i`` (N/(rad/s)², thrust_gain and motor_imbalance included) and a moment about z with
``gear = yaw_sign_i k_m``.  Both take ``ctrl = ω_i²`` in (rad/s)², so the actuators' forces are
qr's rotor map ``F_i = C_T u_i²``, ``Γ_z = Σ yaw_sign_i C_Q u_i²`` (thesis eq. 4.3) in rad/s.
MuJoCo applies a site's force at the site, so the thrusts' moment about the CG is ``Γ - c × T``: the
CG offset is exact.  Aerodynamic and bias terms have no MJCF element: mapping.md lists them with
their size (apply them through ``MjData.xfrc_applied`` if needed).
"""

from __future__ import annotations

from xml.sax.saxutils import quoteattr

import numpy as np

from ..frames import G
from ..sim import plant as pl
from . import mapping as mp
from .mapping import EXACT, IMPOSSIBLE, Row, g

TIMESTEP = 0.001  # s; MuJoCo's RK4 (the rigid body is smooth: 4th order, like qr's plant)


def mjcf(vehicle, pp: mp.Plant, path: str, version: str) -> str:
    name = quoteattr(vehicle.name)
    lines = [f"<!-- {vehicle.name.replace('--', '- -')}: written by qr {version} (qr export, for mujoco); see mapping.md.",
             "     Actuators take ctrl = rotor speed squared, (rad/s)^2: thrust_i = gear ctrl (N), yaw moment_i = gear ctrl (N m). -->",
             f"<mujoco model={name}>",
             '  <compiler angle="radian" inertiafromgeom="false"/>',
             f'  <option timestep="{g(TIMESTEP)}" gravity="0 0 {g(-G)}" integrator="RK4"/>',
             "  <worldbody>",
             f'    <body name={name} pos="0 0 1">',
             '      <freejoint name="root"/>',
             f'      <inertial pos="{g(pp.cg[0])} {g(pp.cg[1])} 0" mass="{g(pp.mass)}" '
             f'diaginertia="{" ".join(g(j) for j in pp.inertia)}"/>']
    radius = 0.25 * pp.arm
    for i, (x, y) in enumerate(pp.rotor_xy, 1):
        lines.append(f'      <site name="rotor{i}" pos="{g(x)} {g(y)} 0" size="{g(radius)}"/>')
        lines.append(f'      <geom name="rotor{i}_disc" type="cylinder" pos="{g(x)} {g(y)} 0" '
                     f'size="{g(radius)} {g(0.02 * radius)}" contype="0" conaffinity="0" mass="0"/>')
    lines += ["    </body>", "  </worldbody>", "  <actuator>"]
    top = g(pp.speed_max**2)
    low = g(pp.speed_min**2)
    for i, (k, s) in enumerate(zip(pp.k_thrust, pp.yaw_signs), 1):
        lines.append(f'    <motor name="thrust{i}" site="rotor{i}" gear="0 0 {g(k)} 0 0 0" '
                     f'ctrllimited="true" ctrlrange="{low} {top}"/>')
        lines.append(f'    <motor name="yaw{i}" site="rotor{i}" gear="0 0 0 0 0 {g(s * pp.k_yaw)}" '
                     f'ctrllimited="true" ctrlrange="{low} {top}"/>')
    lines += ["  </actuator>", "</mujoco>"]
    return "\n".join(lines) + "\n"


def rows(vehicle, pp: mp.Plant) -> list[Row]:
    out = mp.common_rows(vehicle, pp, {
        "mass": ("body/inertial@mass", g(pp.mass) + " kg"),
        "inertia": ("body/inertial@diaginertia", " ".join(g(j) for j in pp.inertia)),
        "thrust_coeff": ("actuator thrust_i@gear[2]", ", ".join(g(k) for k in pp.k_thrust) + " N/(rad/s)²"),
        "torque_coeff": ("actuator yaw_i@gear[5]", ", ".join(g(s * pp.k_yaw) for s in pp.yaw_signs)
                         + " N m/(rad/s)²"),
    })
    out += [
        Row("layout", ", ".join(f"({g(x)}, {g(y)}, {s:+g})" for (x, y), s in zip(pp.rotor_xy, pp.yaw_signs)),
            "site rotor_i@pos; yaw_i gear sign", "(x, y, 0); sign of gear[5]", EXACT,
            "sites in the vehicle file's frame; the yaw gear carries yaw_sign"),
        Row("rotor_speed_min / max", f"{g(vehicle.rotor_speed_min)} / {g(vehicle.rotor_speed_max)} "
            f"{vehicle.rotor_speed_unit}", "actuator@ctrlrange", f"{g(pp.speed_min**2)} {g(pp.speed_max**2)} (rad/s)²",
            EXACT, "ctrl is ω² in (rad/s)²"),
        Row("motor_time_constant", g(vehicle.motor_time_constant) + " s", "-", "-", IMPOSSIBLE,
            "MJCF motors act at once: give ctrl the rotor speeds after your motor model (ctrl = ω(t)²)"),
    ]
    size = mp.sizes(pp)
    P = pp.P
    for name in mp.present(vehicle):
        val = mp.effect_value(vehicle, name)
        if name in ("mass_error", "inertia_error"):
            out.append(Row(name, val, "body/inertial", "(added)", EXACT, "added to the vehicle's value"))
        elif name in ("thrust_gain", "motor_imbalance"):
            out.append(Row(name, val, "actuator thrust_i@gear[2]", ", ".join(g(k) for k in pp.k_thrust), EXACT,
                           "each rotor's C_T × gain (1 + d_i) / f²; its yaw gear unchanged, as in qr"))
        elif name == "yaw_torque_gain":
            out.append(Row(name, val, "actuator yaw_i@gear[5]", g(pp.k_yaw), EXACT, "gain C_Q / f²"))
        elif name == "cg_offset":
            out.append(Row(name, val, "body/inertial@pos", f"{g(pp.cg[0])} {g(pp.cg[1])} 0", EXACT,
                           "thrusts act at the sites: moment about the CG Γ - c × T = the catalog's [-ry T, rx T, 0]"))
        elif name == "marker_offset":
            out.append(Row(name, val, "-", "-", IMPOSSIBLE, f"not a force ({size[name]}): the body's CG is "
                           "data.xipos; the tracked point is xipos + xmat r"))
        elif name in size:
            out.append(Row(name, val, "-", "-", IMPOSSIBLE,
                           f"no MJCF element ({size[name]}): left out; apply it through MjData.xfrc_applied"))
    if P[pl.P_REM_ON]:
        out.append(Row("torque_remainder", "W (3 x 11)", "-", "-", IMPOSSIBLE,
                       f"a learned map ({size['torque_remainder']}): left out; apply it through MjData.xfrc_applied"))
    return out


def write(tmp, vehicle, pp, path: str, version: str) -> list[str]:
    from ..atomic import write_text

    from .rotorpy import file_stem

    name = f"{file_stem(vehicle)}.xml"
    write_text(tmp / name, mjcf(vehicle, pp, path, version))
    return [name]


INTRO = ["The MJCF holds the rigid body and the rotor map (thesis eqs. 4.1, 4.3): ctrl_i = ω_i² in (rad/s)² for "
         "both actuators of rotor i. f = rad/s per rotor-speed unit. MuJoCo's free joint integrates the body "
         "with its own RK4 (timestep " + g(TIMESTEP) + " s)."]


def speeds_to_ctrl(omega: np.ndarray) -> np.ndarray:
    """``MjData.ctrl`` for rotor speeds ω (rad/s, n rotors): thrust and yaw actuator of each rotor get ω²."""
    w2 = np.asarray(omega, float) ** 2
    return np.repeat(w2, 2, axis=-1)
