"""Fly the RotorPy export: the same measured rotor-speed sequence through RotorPy and through qr's plant.

A 2 s window of a measured Crazyflie brushless flight (100 Hz, each rotor scaled so the window's mean
wrench is hover: open loop the vehicle still turns over within the 2 s), held over each sample
(zero-order hold, the motor lag bypassed: the log's speeds are the rotors' own).  RotorPy integrates
with DOP853 at rtol 1e-10, qr's plant with RK4 at 0.625 ms.  The tolerance is 1e-6 of how far the flight
went (its largest displacement, rotation and body rate: up to 17 m, π rad, 100 rad/s): measured, the two
integrators differ by at most 4.4e-8 of it (motor_imbalance; 1.3e-8 flapping, <= 1.4e-9 the others and
the whole extended model), and each effect alone moves the flight by 5.8e-3 (ground effect) to 1.06 of
it, thousands of times the tolerance: a sign or unit error in any term cannot pass.
"""

import numpy as np
import pandas as pd
import pytest

from conftest import DATA, ROOT, VEHICLES
import simulators as S

pytest.importorskip("rotorpy")

from qr.export import mapping as mp  # noqa: E402
from qr.stages.export import run_export  # noqa: E402
from qr.vehicle import load_vehicle, save_vehicle  # noqa: E402

EXTENDED = ROOT / "tests" / "export" / "crazyflie21_brushless_extended.yaml"
DT = 0.01
RTOL = 1e-6  # of the flight's span
ONE_EACH = {  # each catalog effect alone, at sizes like the brushless set's (README)
    "linear_drag": {"kx": 0.0128, "ky": 0.0126, "kz": 0.0098},
    "quadratic_drag": {"cx": 0.01, "cy": 0.012, "cz": 0.02},
    "rotor_drag": {"k": 2e-7},
    "wind_force": {"fx": -0.0004, "fy": 0.0064, "fz": -0.0054},
    "body_force_bias": {"bx": -0.004, "by": -0.005, "bz": -0.009},
    "thrust_gain": {"gain": 1.025},
    "mass_error": {"dm": 0.0017},
    "ground_effect": {"k": 0.0004},
    "motor_imbalance": {"d1": 0.03, "d2": -0.02, "d3": 0.0, "d4": 0.01},
    "cg_offset": {"rx": -0.00034, "ry": 0.00009},
    "torque_bias": {"tx": 1e-5, "ty": -2e-5, "tz": 1e-6},
    "yaw_torque_gain": {"gain": 0.2},
    "inertia_error": {"dJxx": 6.4e-6, "dJyy": 0.0, "dJzz": 0.0},
    "marker_offset": {"rx": 0.003, "ry": -0.001, "rz": 0.018},
    "blade_flapping": {"k": 6.9e-4},
    "rotor_drag_moment": {"k": 2e-7},
    "translational_lift": {"k": 5e-4},
}
NATIVE_EXACT = ("thrust_gain", "mass_error", "cg_offset", "yaw_torque_gain", "inertia_error", "translational_lift")


@pytest.fixture(scope="module")
def speeds(tmp_path_factory):
    """2 s of the measured rotor speeds of brushless flight eckart00 (rpm), trimmed to hover."""
    if not (DATA / "brushless_flights").exists():
        pytest.skip("measured data not available")
    from qr.stages.ingest import ingest

    out = tmp_path_factory.mktemp("flight") / "eckart00.parquet"
    nominal = load_vehicle(VEHICLES / "crazyflie21_brushless.yaml")
    ingest(DATA / "brushless_flights" / "data" / "eckart00", nominal, out)
    df = pd.read_parquet(out).iloc[300:500]
    u = df[["u1", "u2", "u3", "u4"]].to_numpy()
    # the log's 100 Hz (its stamps jitter by ±1 ms): the sequence is held over steps of exactly DT
    assert np.all(np.isfinite(u)) and abs(np.median(np.diff(df["t"].to_numpy())) - DT) < 2e-4
    return S.trimmed(u, nominal)


def export(vehicle, tmp_path):
    path = tmp_path / "vehicle.yaml"
    save_vehicle(vehicle, path)
    run_export(path, "rotorpy", tmp_path / "rp")
    return S.load_module(next((tmp_path / "rp").glob("*_params.py")))


def within(a, b):
    err, span = S.errors(a, b), S.span(a)
    return all(err[k] <= RTOL * span[k] for k in err), err, span


@pytest.mark.parametrize("name", sorted(ONE_EACH))
def test_each_effect_alone_flies_the_same_in_rotorpy(name, speeds, tmp_path):
    vehicle = load_vehicle(VEHICLES / "crazyflie21_brushless.yaml").with_changes(
        effects=[{"name": name, "parameters": ONE_EACH[name]}])
    mod = export(vehicle, tmp_path)
    f = mp.rad_s_per_unit(vehicle)
    x0 = S.hover_start(0.5 if name == "ground_effect" else 1.0)  # in ground effect: 50 cm up
    a = S.qr_fly(vehicle, speeds, DT, x0)
    b = S.rotorpy_fly(mod.QrMultirotor(integrator_kwargs=S.TIGHT), speeds * f, DT, x0)
    if name == "ground_effect":  # up to where it falls to 5 cm (then qr's floor clamp, a kink, acts in both)
        low = np.flatnonzero(a[:, 2] < 0.05)
        n = low[0] if low.size else len(a)
        assert n > 80  # about the first second
        a, b = a[:n], b[:n]
    ok, err, span = within(a, b)
    assert ok, (err, span)
    nominal = S.qr_fly(load_vehicle(VEHICLES / "crazyflie21_brushless.yaml"), speeds, DT, x0)[:len(a)]
    if name != "marker_offset":  # the effect moved the flight far more than the tolerance: the test can fail
        moved = S.errors(a, nominal)
        assert max(moved[k] / span[k] for k in moved) > 100 * RTOL, moved
    else:  # not a force: where the tracked point is
        from qr.sim.plant import tracked_pv

        x = np.concatenate([a[-1], np.zeros(4)])
        r = np.array([ONE_EACH[name][k] for k in ("rx", "ry", "rz")])
        state = S.rotorpy_state(b[-1], np.zeros(4))
        assert np.allclose(mod.tracked_point(state), tracked_pv(x, r)[:3], atol=1e-6)
    if name in NATIVE_EXACT:  # RotorPy's own Multirotor with quad_params alone: the same flight
        from rotorpy.vehicles.multirotor import Multirotor

        c = S.rotorpy_fly(Multirotor(mod.quad_params, initial_state=mod.hover_state(), integrator_kwargs=S.TIGHT),
                          speeds * f, DT, x0)
        ok, err, span = within(a, c)
        assert ok, (err, span)


def test_the_brushless_extended_model_flies_the_same_in_rotorpy(speeds, tmp_path):
    vehicle = load_vehicle(EXTENDED)
    assert len(vehicle.effects) >= 6
    mod = export(vehicle, tmp_path)
    x0 = S.hover_start()
    a = S.qr_fly(vehicle, speeds, DT, x0)
    b = S.rotorpy_fly(mod.QrMultirotor(integrator_kwargs=S.TIGHT), speeds * mp.rad_s_per_unit(vehicle), DT, x0)
    ok, err, span = within(a, b)
    assert ok, (err, span)


def _aero(mod, speeds_rad, v_b, w=np.zeros(3)):
    """RotorPy's aerodynamic wrench alone: its body wrench with aero on minus the one with aero off."""
    from rotorpy.vehicles.multirotor import Multirotor

    on = Multirotor(mod.quad_params, initial_state=mod.hover_state(), aero=True)
    off = Multirotor(mod.quad_params, initial_state=mod.hover_state(), aero=False)
    F1, M1 = on.compute_body_wrench(w, speeds_rad, v_b)
    F0, M0 = off.compute_body_wrench(w, speeds_rad, v_b)
    return F1 - F0, M1 - M0


def test_the_approximate_rotorpy_keys_hold_as_mapping_md_states(tmp_path):
    """k_flap, k_d, c_D: exact under mapping.md's condition, off by exactly the stated error elsewhere."""
    k, kd, c = 6.9e-4, 2e-7, np.array([0.01, 0.012, 0.02])
    vehicle = load_vehicle(VEHICLES / "crazyflie21_brushless.yaml").with_changes(effects=[
        {"name": "blade_flapping", "parameters": {"k": k}}, {"name": "rotor_drag", "parameters": {"k": kd}},
        {"name": "quadratic_drag", "parameters": {"cx": c[0], "cy": c[1], "cz": c[2]}}])
    mod = export(vehicle, tmp_path)
    text = (tmp_path / "rp" / "mapping.md").read_text()
    assert "| blade_flapping | k=0.00069 | k_flap |" in text and "approximate" in text
    f = mp.rad_s_per_unit(vehicle)
    hover = mp.plant_of(vehicle).hover  # rad/s
    rng = np.random.default_rng(1)
    for _ in range(5):
        v = rng.normal(0, 2, 3)
        # the condition: equal rotor speeds summing to 4 ω_hover, no body rate
        F, M = _aero(mod, np.full(4, hover), v)
        qr_M = k * np.array([v[1], -v[0], 0.0])
        qr_F = -kd / f * 4 * hover * np.array([v[0], v[1], 0.0]) - c * np.abs(v) * v  # rotor drag per rad/s
        assert np.allclose(M, qr_M, rtol=1e-9, atol=1e-15)
        # parasitic drag: RotorPy's |v| v_j, qr's |v_j| v_j; the rest of the force is exact
        assert np.allclose(F + c * np.linalg.norm(v) * v - c * np.abs(v) * v, qr_F, rtol=1e-9, atol=1e-15)
        # off hover (equal speeds, sum 4 s ω_hover): the flapping moment is off by exactly |s - 1|
        s = rng.uniform(0.8, 1.2)
        _, M = _aero(mod, np.full(4, s * hover), v)
        assert np.isclose(np.linalg.norm(M - qr_M) / np.linalg.norm(qr_M), abs(s - 1), rtol=1e-9)
    # along one body axis the parasitic drag is exactly qr's
    for j in range(3):
        v = np.zeros(3)
        v[j] = 1.7
        F, _ = _aero(mod, np.full(4, hover), v)
        assert np.isclose(F[j], -kd / f * 4 * hover * v[j] * (j < 2) - c[j] * v[j] * abs(v[j]), rtol=1e-9)


def test_a_hybrid_with_a_learned_torque_remainder_flies_the_same_in_rotorpy(speeds, tmp_path):
    """qr.torque_remainder's W φ (v_b, ω, rotor loads, 1), as a hybrid vehicle file carries it."""
    vehicle = load_vehicle(EXTENDED)
    W = np.random.default_rng(5).normal(0, 2e-6, (3, 11))  # N m per feature unit: ~10 % of the roll torque
    hybrid = vehicle.with_changes(torque_remainder={"weights": W.tolist(), "features": "v_b, omega, loads, 1"})
    mod = export(hybrid, tmp_path)
    x0 = S.hover_start()
    a = S.qr_fly(hybrid, speeds, DT, x0)
    b = S.rotorpy_fly(mod.QrMultirotor(integrator_kwargs=S.TIGHT), speeds * mp.rad_s_per_unit(hybrid), DT, x0)
    ok, err, span = within(a, b)
    assert ok, (err, span)
    moved = S.errors(a, S.qr_fly(vehicle, speeds, DT, x0))
    assert max(moved[k] / span[k] for k in moved) > 100 * RTOL, moved
    row = next(line for line in (tmp_path / "rp" / "mapping.md").read_text().splitlines()
               if line.startswith("| torque_remainder"))
    assert "| exact |" in row


def test_a_hybrid_with_a_learned_wrench_flies_the_same_in_rotorpy(speeds, tmp_path):
    """A hybrid file as ``qr learn residual`` writes it (the brushless extended model with the hub effects, hubs
    1 cm above the CG, a network on every input group, a learned torque remainder): ``qr export --to rotorpy``
    writes the network's weights beside the module, ``QrMultirotor`` evaluates it in NumPy beside qr's hub terms,
    and RotorPy flies what ``qr evaluate``'s rollout integrates for the same file (its kernel, ``rigid_body_rk4``
    on ``true_params`` of the loaded file, the network packed after the plant's slots) to 1e-6 of the span."""
    from qr.vehicle import load_vehicle as load

    extended = load_vehicle(EXTENDED)
    hubs = [{"name": "rotor_drag", "parameters": {"k": 2e-7}}, {"name": "rotor_drag_moment", "parameters": {"k": 2e-7}},
            {"name": "translational_lift", "parameters": {"k": 5e-4}}]
    extended = extended.with_changes(hub_z=0.01, effects=extended.effects + hubs)
    path = S.hybrid_file(extended, tmp_path / "hybrid", force=0.02, torque=2e-5, remainder=2e-6)
    hybrid = load(path)
    run_export(path, "rotorpy", tmp_path / "rp")
    written = sorted(p.name for p in (tmp_path / "rp").iterdir() if not p.name.startswith("."))
    assert written == ["crazyflie21_brushless_params.py", "crazyflie21_brushless_residual.npz", "mapping.md"]
    mod = S.load_module(tmp_path / "rp" / "crazyflie21_brushless_params.py")
    assert "torch" not in mod.__dict__ and mod.NETWORK is not None
    x0 = S.hover_start()
    a = S.qr_fly(hybrid, speeds, DT, x0)
    b = S.rotorpy_fly(mod.QrMultirotor(integrator_kwargs=S.TIGHT), speeds * mp.rad_s_per_unit(hybrid), DT, x0)
    ok, err, span = within(a, b)
    assert ok, (err, span)
    # the network, and the hub terms, each moved the flight far beyond the tolerance: the test can fail
    without = hybrid.with_changes()
    without.residual = None
    no_hubs = hybrid.with_changes(effects=[e for e in hybrid.effects if e["name"] not in ("rotor_drag_moment",
                                                                                           "translational_lift")])
    for other in (without, no_hubs):
        moved = S.errors(a, S.qr_fly(other, speeds, DT, x0))
        assert max(moved[k] / span[k] for k in moved) > 1000 * RTOL, moved
    rows = (tmp_path / "rp" / "mapping.md").read_text().splitlines()
    row = next(line for line in rows if line.startswith("| residual |"))
    assert "| exact |" in row and "RMS over the 1 samples" in row


def test_rotorpys_rotor_drag_and_lift_at_the_hubs_are_qrs_terms(tmp_path):
    """rotor_drag and rotor_drag_moment named with one k, and translational_lift, hubs 1 cm above the CG:
    RotorPy's H-force and lift at the hubs (rotor_drag_matrix = diag(k/f, k/f, 0), k_h = k) give qr's
    catalog moments exactly, at any rotor speeds and body rates; its force is qr's plus the hub part
    -k_d Σ ω_i (ω × r_i)_xy mapping.md states (zero at equal speeds without roll/pitch rate)."""
    from qr.effects import CATALOG, Signals

    k, kl = 2e-7, 5e-4
    vehicle = load_vehicle(VEHICLES / "crazyflie21_brushless.yaml").with_changes(hub_z=0.01, effects=[
        {"name": "rotor_drag", "parameters": {"k": k}}, {"name": "rotor_drag_moment", "parameters": {"k": k}},
        {"name": "translational_lift", "parameters": {"k": kl}}])
    mod = export(vehicle, tmp_path)
    f = mp.rad_s_per_unit(vehicle)
    assert mod.quad_params["k_d"] == pytest.approx(k / f, rel=1e-9) and mod.quad_params["k_h"] == kl
    rows = {r.split(" | ")[0].strip("| "): r for r in (tmp_path / "rp" / "mapping.md").read_text().splitlines()}
    assert "| exact |" in rows["rotor_drag_moment"] and "| exact |" in rows["translational_lift"]
    r = mp.plant_of(vehicle).rotor_pos
    rng = np.random.default_rng(2)
    hover = mp.plant_of(vehicle).hover
    for _ in range(5):
        v, w = rng.normal(0, 2, 3), rng.normal(0, 2, 3)
        omega = hover * rng.uniform(0.8, 1.2, 4)  # rad/s
        F, M = _aero(mod, omega, v, w)
        u = omega / f  # the vehicle's unit
        s = Signals(R=np.eye(3)[None], v_b=v[None], a_b=np.zeros((1, 3)), omega=w[None], alpha=np.zeros((1, 3)),
                    u=u[None], u_dot=np.zeros((1, 4)), p=np.array([[0.0, 0.0, 1.0]]))
        qr = sum(CATALOG[e["name"]].term(e["parameters"], s, vehicle)[0] for e in vehicle.effects)
        np.testing.assert_allclose(M, qr[3:], rtol=1e-9, atol=1e-16)
        hub_part = -k / f * (omega[:, None] * np.cross(w, r)).sum(axis=0) * [1, 1, 0]
        np.testing.assert_allclose(F, qr[:3] + hub_part, rtol=1e-9, atol=1e-16)
    # mapping.md's condition: equal rotor speeds, yaw rate only: RotorPy's force is qr's
    F, _ = _aero(mod, np.full(4, hover), v, np.array([0.0, 0.0, w[2]]))
    s = Signals(R=np.eye(3)[None], v_b=v[None], a_b=np.zeros((1, 3)), omega=np.array([[0.0, 0.0, w[2]]]),
                alpha=np.zeros((1, 3)), u=np.full((1, 4), hover / f), u_dot=np.zeros((1, 4)), p=np.array([[0.0, 0.0, 1.0]]))
    qr = sum(CATALOG[e["name"]].term(e["parameters"], s, vehicle)[0] for e in vehicle.effects)
    np.testing.assert_allclose(F, qr[:3], rtol=1e-9, atol=1e-16)
