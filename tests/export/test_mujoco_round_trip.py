"""Fly the MuJoCo export: its rigid body under qr's rotor thrusts and moments is qr's nominal plant.

The exported MJCF, loaded by MuJoCo itself, driven by 2 s of rotor speeds (ctrl = ω², held over each
10 ms step), against qr's plant on the same speeds: the CG position, attitude and body rate agree to
1e-6 of the flight's span (the issue's 1e-6 relative).  The vehicle carries every term the MJCF body
holds (mass, inertia, CG offset, thrust gain, per-rotor thrust, yaw-torque gain), no aerodynamics.
"""

import numpy as np
import pytest

from conftest import VEHICLES
import simulators as S

mujoco = pytest.importorskip("mujoco")

from qr.export import mapping as mp  # noqa: E402
from qr.export.mujoco import speeds_to_ctrl  # noqa: E402
from qr.stages.export import run_export  # noqa: E402
from qr.vehicle import load_vehicle, save_vehicle  # noqa: E402

RIGID = [{"name": "cg_offset", "parameters": {"rx": 0.002, "ry": -0.001}},
         {"name": "yaw_torque_gain", "parameters": {"gain": 0.2}},
         {"name": "motor_imbalance", "parameters": {"d1": 0.03, "d2": -0.02, "d3": 0.0, "d4": 0.01}},
         {"name": "mass_error", "parameters": {"dm": 0.002}},
         {"name": "inertia_error", "parameters": {"dJxx": 5e-6, "dJyy": 8e-6, "dJzz": 1e-6}},
         {"name": "thrust_gain", "parameters": {"gain": 1.03}}]


def rotor_sequence(vehicle, n=200, seed=3):
    """Hover speeds with a smooth excitation of ±3 % per rotor (rpm)."""
    t = np.arange(n) * 0.01
    rng = np.random.default_rng(seed)
    phase, freq = rng.uniform(0, 2 * np.pi, 4), rng.uniform(0.5, 3, 4)
    return vehicle.hover_speed * (1 + 0.03 * np.sin(2 * np.pi * freq * t[:, None] + phase))


def mujoco_fly(xml, omega, dt, x0, cg, model=None):
    model = mujoco.MjModel.from_xml_path(str(xml)) if model is None else model
    data = mujoco.MjData(model)
    data.qpos[:3] = x0[:3] - np.array([cg[0], cg[1], 0.0])  # the body frame's origin: the CG starts at x0
    data.qpos[3:7] = x0[6:10]
    mujoco.mj_forward(model, data)
    n = int(round(dt / model.opt.timestep))
    assert n * model.opt.timestep == pytest.approx(dt)

    def state():
        return np.concatenate([data.xipos[1], np.zeros(3), data.xquat[1], data.qvel[3:6]])

    out = [state()]
    for w in omega:
        data.ctrl[:] = speeds_to_ctrl(w)
        for _ in range(n):
            mujoco.mj_step(model, data)
        out.append(state())
    return np.array(out)


@pytest.mark.parametrize("effects", [[], RIGID], ids=["nominal", "rigid-body effects"])
def test_the_mjcf_body_flies_qr_nominal_plant(effects, tmp_path):
    vehicle = load_vehicle(VEHICLES / "crazyflie21_brushless.yaml").with_changes(effects=effects)
    save_vehicle(vehicle, tmp_path / "v.yaml")
    run_export(tmp_path / "v.yaml", "mujoco", tmp_path / "mj")
    u = rotor_sequence(vehicle)
    x0 = S.hover_start()
    a = S.qr_fly(vehicle, u, 0.01, x0)
    b = mujoco_fly(tmp_path / "mj" / "crazyflie21_brushless.xml", u * mp.rad_s_per_unit(vehicle), 0.01, x0,
                   mp.plant_of(vehicle).cg)
    err, span = S.errors(a, b), S.span(a)
    assert span["p"] > 0.1 and span["R"] > 0.1 and span["w"] > 0.5  # the flight went somewhere
    for k in err:
        assert err[k] <= 1e-6 * span[k], (k, err, span)


def test_the_mjcf_numbers_are_qr_rotor_map_in_rad_s(tmp_path):
    """By hand: C_T = 4.228755e-10 N/rpm² → 4.228755e-10 / (2π/60)² N/(rad/s)²; C_Q likewise; yaw signs."""
    vehicle = load_vehicle(VEHICLES / "crazyflie21_brushless.yaml")
    run_export(VEHICLES / "crazyflie21_brushless.yaml", "mujoco", tmp_path / "mj")
    model = mujoco.MjModel.from_xml_path(str(tmp_path / "mj" / "crazyflie21_brushless.xml"))
    f = 2 * np.pi / 60
    assert model.body_mass[1] == pytest.approx(0.037, rel=1e-9)
    assert model.body_inertia[1] == pytest.approx([16.571710e-6, 16.655602e-6, 29.261652e-6], rel=1e-9)
    thrust = model.actuator_gear[0::2]
    yaw = model.actuator_gear[1::2]
    assert thrust[:, 2] == pytest.approx([4.228755e-10 / f**2] * 4, rel=1e-9)
    assert yaw[:, 5] == pytest.approx([-2.537253e-12 / f**2, 2.537253e-12 / f**2] * 2, rel=1e-9)
    assert model.site_pos[:, :2] == pytest.approx(vehicle.rotors.positions, rel=1e-9)
    assert model.actuator_ctrlrange[0] == pytest.approx([0, (30000 * f) ** 2], rel=1e-9)


def test_a_hybrids_learned_terms_fly_through_the_control_callback(tmp_path):
    """A hybrid as ``qr learn residual`` writes it (every rigid-body term, a network on every input group, a
    learned torque remainder): the MJCF plus ``<name>_learned_wrench.py`` installed as MuJoCo's control callback
    fly qr's plant (the kernel of ``qr evaluate``'s rollout on the loaded file) to 1e-6 of the span; the MJCF
    alone, without the callback, does not (the learned terms moved the flight far beyond the tolerance)."""
    vehicle = load_vehicle(VEHICLES / "crazyflie21_brushless.yaml").with_changes(effects=RIGID)
    path = S.hybrid_file(vehicle, tmp_path / "hybrid", force=0.02, torque=2e-5, remainder=2e-6)
    hybrid = load_vehicle(path)
    run_export(path, "mujoco", tmp_path / "mj")
    written = sorted(p.name for p in (tmp_path / "mj").iterdir() if not p.name.startswith("."))
    assert written == ["crazyflie21_brushless.xml", "crazyflie21_brushless_learned_wrench.py",
                       "crazyflie21_brushless_residual.npz", "mapping.md"]
    learned = S.load_module(tmp_path / "mj" / "crazyflie21_brushless_learned_wrench.py")
    u = rotor_sequence(hybrid)
    x0 = S.hover_start()
    a = S.qr_fly(hybrid, u, 0.01, x0)
    xml = tmp_path / "mj" / "crazyflie21_brushless.xml"
    cg = mp.plant_of(hybrid).cg
    model = mujoco.MjModel.from_xml_path(str(xml))  # first: MuJoCo compiles no model under a Python callback
    with learned.installed(model) as wrench:
        assert mujoco.get_mjcb_control() is wrench
        b = mujoco_fly(xml, u * mp.rad_s_per_unit(hybrid), 0.01, x0, cg, model)
    assert mujoco.get_mjcb_control() is None  # the previous callback (none) is back
    err, span = S.errors(a, b), S.span(a)
    assert span["p"] > 0.1 and span["R"] > 0.1 and span["w"] > 0.5
    for k in err:
        assert err[k] <= 1e-6 * span[k], (k, err, span)
    alone = S.errors(a, mujoco_fly(xml, u * mp.rad_s_per_unit(hybrid), 0.01, x0, cg))
    assert max(alone[k] / span[k] for k in alone) > 1000 * 1e-6, alone
    rows = (tmp_path / "mj" / "mapping.md").read_text().splitlines()
    for item in ("residual", "torque_remainder"):
        row = next(line for line in rows if line.startswith(f"| {item} |"))
        assert "| exact |" in row and "learned_wrench.py" in row, row
