"""``qr export --to mujoco``: an MJCF model, ``<name>.xml`` (and, for a hybrid, the module that applies its
learned terms).

One free body (the vehicle file's body frame, ``<inertial>`` at the CG), one site per rotor hub with a thrust
(``gear = k_i``) and a yaw-moment (``gear = yaw_sign_i k_m``) actuator on ``ctrl = ω_i²``; learned terms through
``MjData.xfrc_applied`` from MuJoCo's control callback.  The derivation: docs/export.md "How each convention
was derived", "A hybrid in each simulator".
"""

from __future__ import annotations

import textwrap
from xml.sax.saxutils import quoteattr

import numpy as np

from ..frames import G
from .. import plant_state as ps
from . import learned, mapping as mp
from .mapping import EXACT, IMPOSSIBLE, File, Row, file_stem, g

TIMESTEP = 0.001  # s; MuJoCo's RK4 (the rigid body is smooth: 4th order, like qr's plant)


def mjcf(vehicle, pp: mp.Plant, path: str, version: str) -> str:
    name = quoteattr(vehicle.name)
    lines = [f"<!-- {vehicle.name.replace('--', '- -')}: written by qr {version} (qr export, for mujoco); see mapping.md.",
             "     Actuators take ctrl = rotor speed squared, (rad/s)^2: thrust_i = gear ctrl (N), yaw moment_i = gear ctrl (N m)."
             + (f"\n     The learned terms: {wrench_module(vehicle)}.py beside this file (mjcb_control)."
                if has_learned(vehicle, pp) else "") + " -->",
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
    for i, (k, kq, s) in enumerate(zip(pp.k_thrust, pp.k_yaw, pp.yaw_signs), 1):
        lines.append(f'    <motor name="thrust{i}" site="rotor{i}" gear="0 0 {g(k)} 0 0 0" '
                     f'ctrllimited="true" ctrlrange="{low} {top}"/>')
        lines.append(f'    <motor name="yaw{i}" site="rotor{i}" gear="0 0 0 0 0 {g(s * kq)}" '
                     f'ctrllimited="true" ctrlrange="{low} {top}"/>')
    lines += ["  </actuator>", "</mujoco>"]
    return "\n".join(lines) + "\n"


def has_learned(vehicle, pp: mp.Plant) -> bool:
    """Whether the vehicle carries a learned term (a network, a torque remainder) the MJCF cannot hold."""
    return vehicle.residual is not None or bool(pp.P[ps.P_REM_ON])


def wrench_module(vehicle) -> str:
    return f"{file_stem(vehicle)}_learned_wrench"


WRENCH_MODULE = '''"""{name} for MuJoCo: the learned terms of qr's model, which no MJCF element holds.

{intro}

    import mujoco
    import {module} as learned
    model = mujoco.MjModel.from_xml_path("{xml}")
    data = mujoco.MjData(model)
    with learned.installed(model):                  # mujoco.set_mjcb_control(LearnedWrench(model))
        data.ctrl[:] = learned.speeds_to_ctrl(omega)   # rotor speeds (rad/s) -> ctrl = omega^2
        mujoco.mj_step(model, data)

Installed as the control callback, the wrench is evaluated wherever MuJoCo evaluates the dynamics (at
each of the 4 stages of its RK4 step), as qr's plant evaluates it.  Without the callback, calling
wrench = LearnedWrench(model); wrench(model, data) before each mj_step holds it over the step (an error
of first order in the step).  The callback owns the body's row of xfrc_applied: put your own pushes in
wrench.extra (6 numbers, world frame: force N, torque N m).  MuJoCo has one control callback per process,
and compiles no model while a Python one is installed: load the models first, install after.
The network is evaluated in NumPy from its weights beside this module (no torch, no qr needed).
"""
import contextlib
import os

import mujoco
import numpy as np

BODY = {body!r}
N_ROTORS = {n}
CG = np.array([{cg}], float)  # m: the CG in the body frame (the MJCF's inertial pos)

# SI units, rotor speeds in rad/s, body frame.
TERMS = {{
{terms}
}}
RESIDUAL = TERMS["residual"]
REMAINDER = None if TERMS["torque_remainder"] is None else np.asarray(TERMS["torque_remainder"], float)
REMAINDER_HOVER_SPEED = TERMS["remainder_hover_speed"]

{network}

def speeds_to_ctrl(omega):
    """MjData.ctrl for rotor speeds omega (rad/s): the thrust and yaw actuators of each rotor get omega^2."""
    return np.repeat(np.asarray(omega, float) ** 2, 2, axis=-1)


def _rotation(q):
    """Body -> world rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


class LearnedWrench:
    """The control callback: the learned wrench of the current state into data.xfrc_applied[body]."""

    def __init__(self, model):
        self.body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, BODY)
        joint = model.body_jntadr[self.body]
        self.qpos, self.qvel = model.jnt_qposadr[joint], model.jnt_dofadr[joint]
        self.thrust = np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, f"thrust{{i}}")
                                for i in range(1, N_ROTORS + 1)])
        self.extra = np.zeros(6)

    def rotor_speeds(self, model, data):
        """Rotor speeds (rad/s) from the thrust actuators' ctrl (clamped to their range, as MuJoCo clamps it)."""
        lo, hi = model.actuator_ctrlrange[self.thrust].T
        return np.sqrt(np.clip(data.ctrl[self.thrust], lo, hi))

    def body_wrench(self, model, data):
        """(force N, torque N m): the learned terms in the body frame, at the CG."""
        R = _rotation(data.qpos[self.qpos + 3:self.qpos + 7])
        omega = np.array(data.qvel[self.qvel + 3:self.qvel + 6])  # body frame (free joint)
        v_b = R.T @ data.qvel[self.qvel:self.qvel + 3] + np.cross(omega, CG)  # the CG's velocity, body frame
        force, torque = learned_wrench(v_b, omega, -R[2], self.rotor_speeds(model, data))  # g_b = R^T [0, 0, -1]
        return force, torque, R

    def __call__(self, model, data):
        force, torque, R = self.body_wrench(model, data)
        data.xfrc_applied[self.body, :3] = R @ force + self.extra[:3]
        data.xfrc_applied[self.body, 3:] = R @ torque + self.extra[3:]


@contextlib.contextmanager
def installed(model):
    """LearnedWrench(model) as MuJoCo's control callback inside the block (the previous one restored after)."""
    previous = mujoco.get_mjcb_control()
    wrench = LearnedWrench(model)
    mujoco.set_mjcb_control(wrench)
    try:
        yield wrench
    finally:
        mujoco.set_mjcb_control(previous)
'''


def wrench_terms(vehicle, pp: mp.Plant) -> dict:
    P = pp.P
    rem = P[ps.P_REM].reshape(3, 11) if P[ps.P_REM_ON] else None
    return {"torque_remainder": None if rem is None else [list(r) for r in rem],  # N m per feature
            "remainder_hover_speed": learned.Exact([P[ps.P_UHOVER] * pp.unit]),  # rad/s
            "residual": learned.residual_spec(vehicle, pp, file_stem(vehicle))}


def wrench_text(vehicle, pp: mp.Plant, path: str, version: str) -> str:
    what = " and ".join(w for w, on in (("the learned torque remainder", pp.P[ps.P_REM_ON]),
                                        ("the learned wrench (the network of qr learn residual)",
                                         vehicle.residual is not None)) if on)
    terms = "\n".join(f"    '{k}': {learned.literal(v, lambda x: repr(float(x)))}," for k, v in
                      wrench_terms(vehicle, pp).items())
    intro = textwrap.fill(f"Written by `qr export {path} --to mujoco` (qr {version}) beside {file_stem(vehicle)}.xml. "
                          f"The MJCF holds the rigid body and the rotors; this module adds {what} as "
                          f"MjData.xfrc_applied on the body {vehicle.name!r}, at its CG, from the body's state and "
                          "the rotor speeds (omega_i = sqrt(ctrl) of actuator thrust<i>):", 108)
    return WRENCH_MODULE.format(name=vehicle.name, intro=intro, xml=f"{file_stem(vehicle)}.xml", body=vehicle.name, module=wrench_module(vehicle), n=len(pp.yaw_signs),
                                cg=", ".join(repr(float(x)) for x in (pp.cg[0], pp.cg[1], 0.0)), terms=terms,
                                network=learned.LEARNED_SOURCE)


def rows(vehicle, pp: mp.Plant) -> list[Row]:
    """The mapping of every key, parameter and named effect of the vehicle file onto the MJCF (and the module)."""
    rx, ry = mp.fx_cg(vehicle)
    out = mp.common_rows(vehicle, pp, {
        "name": ("mujoco@model, body@name", vehicle.name, ""),
        "mass": ("body/inertial@mass", g(pp.mass) + " kg", mp.fx_mass(vehicle)),
        "inertia": ("body/inertial@diaginertia", " ".join(g(j) for j in pp.inertia),
                    ", ".join(mp.fx_inertia(vehicle))),
        "thrust_coeff": ("actuator thrust_i@gear[2]", ", ".join(g(k) for k in pp.k_thrust) + " N/(rad/s)²",
                         mp.fx_k_thrust(vehicle)),
        "torque_coeff": ("actuator yaw_i@gear[5]", ", ".join(g(s * kq) for s, kq in zip(pp.yaw_signs, pp.k_yaw))
                         + " N m/(rad/s)²", "s_i · " + mp.fx_k_yaw(vehicle),
                         f"C_Q per {vehicle.rotor_speed_unit}² → per (rad/s)²: ÷ f²; the sign: yaw_sign"),
    })
    out += [
        Row("layout (rotor x, y)", ", ".join(f"({g(x)}, {g(y)})" for x, y in vehicle.rotors.positions),
            "site rotor_i@pos", ", ".join(f"({g(x)}, {g(y)}, 0)" for x, y in pp.rotor_xy), EXACT,
            "sites in the vehicle file's frame (its origin, not the CG: the inertial pos carries the CG)",
            formula="(x_i, y_i, 0)"),
        Row("layout (yaw_sign)", ", ".join(f"{s:+g}" for s in vehicle.rotors.yaw_signs), "actuator yaw_i@gear[5]",
            "signs " + ", ".join("+" if s > 0 else "−" for s in pp.yaw_signs), EXACT,
            "the yaw gear carries yaw_sign (torque_coeff row)"),
        Row("rotor_speed_min, rotor_speed_max", f"{g(vehicle.rotor_speed_min)}, {g(vehicle.rotor_speed_max)} "
            f"{vehicle.rotor_speed_unit}", "actuator@ctrlrange", f"{g(pp.speed_min**2)}, {g(pp.speed_max**2)} (rad/s)²",
            EXACT, "ctrl is ω² in (rad/s)²", formula="(f · u_min)², (f · u_max)²"),
        Row("motor_time_constant", g(vehicle.motor_time_constant) + " s", "-", "-", IMPOSSIBLE,
            "MJCF motors act at once: give ctrl the rotor speeds after your motor model (ctrl = ω(t)²)"),
        mp.ground_row(vehicle),
        mp.hub_row(vehicle, "site rotor_i@pos (z)"),
    ]
    size = mp.sizes(pp)
    for name in mp.present(vehicle):
        val = mp.effect_value(vehicle, name)
        if name in ("mass_error", "inertia_error"):
            out.append(Row(name, val, "body/inertial", "(added)", EXACT, "added to the vehicle's value (mass, "
                           "inertia rows)"))
        elif name in ("thrust_gain", "motor_imbalance"):
            out.append(Row(name, val, "actuator thrust_i@gear[2]", ", ".join(g(k) for k in pp.k_thrust), EXACT,
                           "each rotor's C_T × gain (1 + d_i) / f²" + ("; its yaw gear C_Q (1 + d_i − mean d) / f², as "
                                                                      "in qr" if name == "motor_imbalance" else ""),
                           formula=mp.fx_k_thrust(vehicle)))
        elif name == "yaw_torque_gain":
            out.append(Row(name, val, "actuator yaw_i@gear[5]",
                           ", ".join(g(s * kq) for s, kq in zip(pp.yaw_signs, pp.k_yaw)),
                           EXACT, "yaw_sign gain C_Q / f²", formula="s_i · " + mp.fx_k_yaw(vehicle)))
        elif name == "cg_offset":
            out.append(Row(name, val, "body/inertial@pos", f"{g(pp.cg[0])} {g(pp.cg[1])} 0", EXACT,
                           "thrusts act at the sites: moment about the CG Γ - c × T = the catalog's [-ry T, rx T, 0]",
                           formula=f"{rx}, {ry}, 0"))
        elif name == "marker_offset":
            out.append(Row(name, val, "-", "-", IMPOSSIBLE, f"not a force ({size[name]}): the body's CG is "
                           "data.xipos; the tracked point is xipos + xmat r"))
        elif name in size:
            out.append(Row(name, val, "-", "-", IMPOSSIBLE,
                           f"no MJCF element ({size[name]}): left out; apply it through MjData.xfrc_applied"))
    return out + _learned_rows(vehicle, pp, size)


def _learned_rows(vehicle, pp: mp.Plant, size: dict) -> list[Row]:
    """The learned terms: applied by the module beside the MJCF."""
    out, module = [], wrench_module(vehicle)
    if pp.P[ps.P_REM_ON]:
        out.append(Row("torque_remainder", "W (3 × 11)", f"{module}.py: LearnedWrench (xfrc_applied)",
                       "the file's W", EXACT,
                       f"a learned map, no MJCF element: the module's control callback adds W φ to the body's torque "
                       f"at every evaluation of the dynamics; the MJCF alone lacks it ({size['torque_remainder']})"))
    if vehicle.residual is not None:
        out.append(Row("residual", mp.residual_item(vehicle),
                       f"{module}.py: LearnedWrench (xfrc_applied); {learned.residual_file(file_stem(vehicle))}",
                       "the file's network", EXACT,
                       "a learned body wrench, no MJCF element: the module's control callback (mjcb_control) evaluates "
                       "the network in NumPy at every RK4 stage and applies its force and torque at the body's CG "
                       f"(xfrc_applied); the MJCF alone lacks it. Its size: {mp.residual_size(vehicle, pp)}"))
    return out


def files(vehicle, pp: mp.Plant, path: str, version: str) -> list[File]:
    """``<name>.xml`` and, for a vehicle with learned terms, the module that applies them and the network's weights."""
    out = [File(f"{file_stem(vehicle)}.xml", mjcf(vehicle, pp, path, version))]
    if has_learned(vehicle, pp):
        out += [File(f"{wrench_module(vehicle)}.py", wrench_text(vehicle, pp, path, version)),
                *learned.weights(vehicle, file_stem(vehicle))]
    return out


INTRO = ["The MJCF holds the rigid body and the rotor map (thesis eqs. 4.1, 4.3): ctrl_i = ω_i² in (rad/s)² for "
         "both actuators of rotor i. f = rad/s per rotor-speed unit. MuJoCo's free joint integrates the body "
         "with its own RK4 (timestep " + g(TIMESTEP) + " s). A hybrid's learned terms (network, torque remainder) "
         "are applied by the module `<name>_learned_wrench.py` written beside the MJCF (MuJoCo's control callback "
         "setting `xfrc_applied`); the rows marked exact for them hold with it installed."]


def speeds_to_ctrl(omega: np.ndarray) -> np.ndarray:
    """``MjData.ctrl`` for rotor speeds ω (rad/s, n rotors): thrust and yaw actuator of each rotor get ω²."""
    w2 = np.asarray(omega, float) ** 2
    return np.repeat(w2, 2, axis=-1)
