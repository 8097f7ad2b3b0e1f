"""The rollout's differentiable twin (qr.rollout_torch) is the compiled plant (qr.sim.plant, qr.rollout).

On random states and inputs, for the nominal vehicle and with every catalog effect (and the linear
torque remainder and a learned wrench, or the rotor inertia, per-rotor yaw gains and flapping ratio), the
torch derivative, RK4 step and whole windows' errors equal the compiled ones to 1e-9; gradients reach the physical parameters; the prediction at step h
never depends on a later input; a learned wrench flies wherever the vehicle does (a constant one is
the catalog's body_force_bias + torque_bias in qr synth, the rollout, the replay and the study).
"""

import numpy as np
import pandas as pd
import pytest
import torch

from learning_data import residual_wrench
from qr import residual as rs
from qr import rollout
from qr import rollout_torch as rt
from qr.effects import CATALOG, parse_effect_spec
from qr.plant_state import N_P, P_DELAY, P_J, P_SCALE
from qr.sim.plant import rigid_body_deriv, rigid_body_rk4, true_params

EFFECTS = {  # every catalog effect, at sizes a rollout notices (the Hummingbird's scale)
    "linear_drag": "kx=0.3,ky=0.2,kz=0.1", "quadratic_drag": "cx=0.1,cy=0.15,cz=0.05", "rotor_drag": "k=1e-5",
    "wind_force": "fx=0.5,fy=-0.3,fz=0.2", "body_force_bias": "bx=0.1,by=-0.2,bz=0.3", "thrust_gain": "gain=1.08",
    "mass_error": "dm=0.05", "ground_effect": "k=0.005", "motor_imbalance": "d1=0.05,d2=-0.03,d3=0.02,d4=0.0",
    "cg_offset": "rx=0.01,ry=-0.005", "torque_bias": "tx=0.01,ty=-0.01,tz=0.005", "yaw_torque_gain": "gain=1.2",
    "inertia_error": "dJxx=0.001,dJyy=0.0015,dJzz=0.002", "marker_offset": "rx=0.02,ry=-0.01,rz=0.03",
    "blade_flapping": "k=0.02", "actuator_delay": "delay_s=0.025", "rotor_drag_moment": "k=1e-5",
    "translational_lift": "k=0.01",
}


def _place(P0, *values) -> torch.Tensor:
    """``P0`` (the plant's vector) as a tensor with ``values`` (pairs of a slot of :mod:`qr.plant_state` and a
    tensor) put at their slots, differentiably: e.g. ``(P_J, J), (P_SCALE, c_t / c_t0 * ones(4)), (P_CQGAIN, k)``."""
    P = torch.as_tensor(np.asarray(P0, float)[:N_P], dtype=rt.DTYPE).clone()
    for slot, v in values:
        i = slot.start if isinstance(slot, slice) else slot
        v = torch.as_tensor(v, dtype=rt.DTYPE).reshape(-1)
        P = torch.cat([P[:i], v, P[i + len(v):]])
    return P


def _delayed_inputs(t: np.ndarray, U: np.ndarray, d: torch.Tensor) -> torch.Tensor:
    """The rotor speeds acting at each stamp for a delay ``d`` (s), differentiably in ``d``
    (``np.interp(t − d, t, U)``, as :meth:`qr.rollout.Windows.inputs`)."""
    Ut = torch.as_tensor(U, dtype=rt.DTYPE)
    if float(d.detach()) <= 0:
        return Ut
    s = torch.as_tensor(np.array(t, float), dtype=rt.DTYPE) - d
    k = np.clip(np.searchsorted(t, s.detach().numpy(), side="right") - 1, 0, len(t) - 2)
    t0, t1 = torch.as_tensor(t[k], dtype=rt.DTYPE), torch.as_tensor(t[k + 1], dtype=rt.DTYPE)
    f = torch.clamp((s - t0) / (t1 - t0), 0.0, 1.0)[:, None]
    return (1 - f) * Ut[k] + f * Ut[k + 1]


def _net(vehicle, activation="tanh", depth=2, seed=0):
    """A learned wrench with random (non-zero) weights of the vehicle's scale."""
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    inputs = ["v_b", "omega", "g_b", "u2"] if activation == "tanh" else ["v_b", "omega", "u"]
    n = sum(rs.GROUPS[g] for g in inputs)
    return rt.ResidualNet(inputs, 16, depth, activation, rng.normal(0, 0.3, n), rng.uniform(0.5, 2, n),
                          np.array([0.5, 0.5, 1.0, 0.05, 0.05, 0.02]), vehicle.hover_speed)


def _case(name, hummingbird):
    v = hummingbird
    effects = []
    if name in ("effects", "all", "rotors"):
        assert set(EFFECTS) == set(CATALOG)
        effects = [parse_effect_spec(f"{k}:{p}") for k, p in EFFECTS.items()]
        v = v.with_changes(hub_z=0.03)  # hubs above the CG: the hub effects' roll and pitch parts too
    if name == "rotors":  # the rotor and airframe properties the catalog lacks (qr.vehicle.ROTOR_PROPERTIES)
        v = v.with_changes(rotor_inertia=6e-5, rotor_torque_gains=[1.1, 0.9, 1.05, 0.97], flapping_pitch_ratio=1.4)
    net = None
    if name == "all":
        W = np.random.default_rng(5).normal(0, 0.01, (3, 11))
        v = v.with_changes(torque_remainder={"weights": W.tolist()})
        net = _net(v)
        v.residual = net.to_residual()
    if name == "relu":
        net = _net(v, "relu", depth=1)
        v = v.with_changes()
        v.residual = net.to_residual()
    return v, effects, net


def _states(rng, n, vehicle):
    x = np.zeros((n, 13))
    x[:, 0:2] = rng.normal(0, 1, (n, 2))
    x[:, 2] = rng.uniform(0.05, 2.0, n)  # heights near the floor too (the ground effect)
    x[:, 3:6] = rng.normal(0, 2, (n, 3))
    q = rng.normal(0, 1, (n, 4)) + [3, 0, 0, 0]
    x[:, 6:10] = q / np.linalg.norm(q, axis=1, keepdims=True)
    x[:, 10:13] = rng.normal(0, 2, (n, 3))
    u = vehicle.hover_speed * rng.uniform(0.7, 1.3, (n, 4))
    return x, u


CASES = ["nominal", "effects", "all", "relu", "rotors"]


@pytest.mark.parametrize("case", CASES)
def test_derivative_and_rk4_step_equal_the_compiled_plant(case, hummingbird):
    vehicle, effects, net = _case(case, hummingbird)
    P = true_params(vehicle, effects)
    assert (len(P) > N_P) == (net is not None)  # the network rides at the end of the vector
    x, u = _states(np.random.default_rng(1), 200, vehicle)
    dx, xn = np.empty((200, 13)), np.empty((200, 13))
    zero, k, xs = np.zeros(3), np.empty((4, 13)), np.empty(13)
    dt = 0.01
    for i in range(200):
        rigid_body_deriv(x[i], u[i], P, zero, zero, dx[i])
        rigid_body_rk4(x[i], u[i], u[i], u[i], P, dt, False, zero, k, xs, xn[i])
    Pt = torch.as_tensor(P[:N_P])
    X, U = torch.as_tensor(x), torch.as_tensor(u)
    got = rt.deriv(X, U, Pt, net).detach().numpy()
    np.testing.assert_allclose(got, dx, rtol=1e-9, atol=1e-9)
    step = rt.rk4(X, U, torch.full((200,), dt, dtype=torch.float64), Pt, net).detach().numpy()
    np.testing.assert_allclose(step, xn, rtol=1e-9, atol=1e-12)
    if net is not None:  # the network's own forward, the compiled one and the NumPy reference agree
        from qr.frames import quat_to_rot

        R = quat_to_rot(x[:, 6:10])
        phi = rs.features(net.inputs, np.einsum("nji,nj->ni", R, x[:, 3:6]), x[:, 10:13], -R[:, 2, :], u,
                          vehicle.hover_speed)
        np.testing.assert_allclose(residual_wrench(vehicle.residual, phi),
                                   net(torch.as_tensor(phi)).detach().numpy(), rtol=1e-12, atol=1e-15)


def _piece(rng, vehicle, n=120, H=15):
    """A jittery random 'flight' piece: start states, rotor speeds with a held dropout, truth with gaps."""
    t = np.cumsum(rng.uniform(0.008, 0.012, n))
    x, u = _states(rng, n, vehicle)
    x[:, 10:13] *= 0.3
    states = pd.DataFrame(x, columns=rollout.POSITION + rollout.VELOCITY + rollout.QUATERNION + rollout.RATE)
    states.insert(0, "t", t)
    meas = states[["t"] + rollout.POSITION + rollout.QUATERNION].copy()
    meas[rollout.POSITION] += rng.normal(0, 0.01, (n, 3))
    meas.loc[rng.choice(n, 8, replace=False), rollout.POSITION] = np.nan
    meas.loc[rng.choice(n, 5, replace=False), rollout.QUATERNION] = np.nan
    meas[rollout.ROTORS] = u
    meas.loc[[40, 41], rollout.ROTORS] = np.nan  # a short gap, held over
    return rollout.windows(states, meas, H, 2)


@pytest.mark.parametrize("case", CASES)
def test_whole_windows_equal_the_compiled_rollout(case, hummingbird):
    """Per-step errors of each window (marker offset, actuator delay, held rotor speeds, missing truth):
    the compiled rollout's sums and counts, window by window."""
    vehicle, effects, net = _case(case, hummingbird)
    P = true_params(vehicle, effects)
    H = 15
    w = _piece(np.random.default_rng(2), vehicle, H=H)
    Ud = _delayed_inputs(w.t, w.U, torch.as_tensor(P[P_DELAY]))
    np.testing.assert_allclose(Ud.numpy(), w.inputs(P), rtol=1e-12)
    starts = [s for s in (0, 7, 33, 60, 100) if w.ok[s] and s + H < len(w.t)]
    assert len(starts) >= 4
    j = np.array(starts)[:, None] + np.arange(1, H + 1)
    t = lambda a: torch.as_tensor(np.array(a))  # noqa: E731
    pred = rt.rollout(t(w.X0[starts]), Ud[j - 1], t(w.t[j] - w.t[j - 1]), t(P[:N_P]), net)
    E = rt.window_errors(pred, t(w.tp[j]), t(w.tq[j]), t(w.tv[j]), t(w.tw[j])).detach().numpy()
    for b, s in enumerate(starts):
        keep = np.zeros(len(w.t), bool)
        keep[s] = True
        one = rollout.Windows(w.t, w.X0, w.U, keep, w.tp, w.tq, w.tv, w.tw)
        sums, counts = rollout.score_plant(one, H, P)
        np.testing.assert_array_equal(counts, np.isfinite(E[b]).astype(int))
        np.testing.assert_allclose(np.nan_to_num(E[b]), sums, rtol=1e-9, atol=1e-11)
    assert np.nanmax(E[:, -1, 0]) > 0.01  # the windows move (errors well above rounding)


def test_gradients_reach_the_physical_parameters(hummingbird):
    """d(error)/dJ and d(error)/dC_T through :func:`place` agree with central differences of the compiled rollout."""
    vehicle, effects, _ = _case("effects", hummingbird)
    P0 = true_params(vehicle, effects)
    H = 12
    w = _piece(np.random.default_rng(3), vehicle, H=H)
    s = 20
    j = s + np.arange(1, H + 1)
    J = torch.tensor(P0[P_J], requires_grad=True)
    c = torch.tensor(1.0, dtype=torch.float64, requires_grad=True)  # C_T / C_T(file)
    P = _place(P0, (P_J, J), (P_SCALE, c * torch.as_tensor(P0[P_SCALE])))
    Ud = _delayed_inputs(w.t, w.U, P[P_DELAY])
    t = lambda a: torch.as_tensor(np.array(a))[None]  # noqa: E731
    E = rt.window_errors(rt.rollout(t(w.X0[s]), Ud[j - 1][None], t(w.t[j] - w.t[j - 1]), P),
                         t(w.tp[j]), t(w.tq[j]), t(w.tv[j]), t(w.tw[j]))
    torch.nan_to_num(E[0, :, 3]).sum().backward()  # the summed rate error of the window

    def compiled(Pn):
        keep = np.zeros(len(w.t), bool)
        keep[s] = True
        return rollout.score_plant(rollout.Windows(w.t, w.X0, w.U, keep, w.tp, w.tq, w.tv, w.tw), H, Pn)[0][:, 3].sum()

    for k in range(3):
        eps = 1e-6 * P0[P_J.start + k]
        hi, lo = P0.copy(), P0.copy()
        hi[P_J.start + k] += eps
        lo[P_J.start + k] -= eps
        assert J.grad[k].item() == pytest.approx((compiled(hi) - compiled(lo)) / (2 * eps), rel=1e-5)
    hi, lo = P0.copy(), P0.copy()
    hi[P_SCALE] *= 1 + 1e-6
    lo[P_SCALE] *= 1 - 1e-6
    assert c.grad.item() == pytest.approx((compiled(hi) - compiled(lo)) / 2e-6, rel=1e-5)


def test_the_prediction_at_step_h_never_reads_a_later_sample(hummingbird):
    """Causality: changing the inputs of steps > h (and every truth) leaves the prediction up to h and its
    errors unchanged; the residual's inputs are instantaneous states and rotor speeds only."""
    vehicle, _, net = _case("all", hummingbird)
    P = torch.as_tensor(true_params(vehicle)[:N_P])
    x, u = _states(np.random.default_rng(4), 6, vehicle)
    H, h = 10, 4
    U = torch.as_tensor(np.repeat(u[:, None], H, 1))
    dt = torch.full((6, H), 0.01, dtype=torch.float64)
    a = rt.rollout(torch.as_tensor(x), U, dt, P, net)
    U2 = U.clone()
    U2[:, h:] *= 1.3
    b = rt.rollout(torch.as_tensor(x), U2, dt, P, net)
    assert torch.equal(a[:, :h], b[:, :h]) and not torch.allclose(a[:, h:], b[:, h:])
    assert set(rs.GROUPS) == {"v_b", "omega", "g_b", "u", "u2"}  # no acceleration, no later sample


def test_a_zero_residual_changes_nothing(hummingbird):
    """A network with a zero last layer: the compiled rollout's sums are bit for bit the vehicle's own."""
    net = _net(hummingbird)
    with torch.no_grad():
        net.layers[-1].weight.zero_()
        net.layers[-1].bias.zero_()
    hybrid = hummingbird.with_changes()
    hybrid.residual = net.to_residual()
    w = _piece(np.random.default_rng(6), hummingbird, H=15)
    a = rollout.score_plant(w, 15, true_params(hummingbird))
    b = rollout.score_plant(w, 15, true_params(hybrid))
    assert len(true_params(hybrid)) > N_P
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


def _constant(vehicle, wrench):
    """A learned wrench that is a constant body force and torque (a network with no hidden layer, zero weights)."""
    n = 3
    return rs.Residual(("v_b",), "tanh", (np.zeros((6, n)),), (np.asarray(wrench, float) / 0.1,), np.zeros(n),
                       np.ones(n), np.full(6, 0.1), vehicle.hover_speed)


def test_a_constant_residual_flies_as_the_catalogs_bias_everywhere(hummingbird, tmp_path):
    """A body force and torque at the CG is what body_force_bias + torque_bias mean: qr synth's plant, the
    rollout of qr evaluate and the replay of qr diagnose fly the residual vehicle exactly like that one."""
    from qr.diagnose.replay import replay
    from qr.sim.synth import SynthConfig, simulate_truth
    from qr.vehicle import load_vehicle, save_vehicle

    wrench = [0.3, -0.2, 0.5, 0.01, -0.02, 0.005]
    effects = [parse_effect_spec("body_force_bias:bx=0.3,by=-0.2,bz=0.5"),
               parse_effect_spec("torque_bias:tx=0.01,ty=-0.02,tz=0.005")]
    res = _constant(hummingbird, wrench)
    # through a vehicle file (model path relative to it) and back
    rs.save_weights(res, tmp_path / "m.npz")
    raw = hummingbird.to_dict()
    raw["residual"] = rs.block(res, str(tmp_path / "m.npz"), "test")
    (tmp_path / "sub").mkdir()
    save_vehicle(raw, tmp_path / "sub" / "h.yaml")
    assert "model: ../m.npz" in (tmp_path / "sub" / "h.yaml").read_text()
    hybrid = load_vehicle(tmp_path / "sub" / "h.yaml")
    cfg = SynthConfig(duration=6, rate=100, seed=4, noise_free=True)
    a = simulate_truth(hybrid, [], cfg)
    b = simulate_truth(hummingbird, effects, cfg)
    np.testing.assert_allclose(a.to_numpy(), b.to_numpy(), rtol=1e-9, atol=1e-9)
    c = simulate_truth(hummingbird, [], cfg)
    assert np.abs(a[["px", "py", "pz"]].to_numpy() - c[["px", "py", "pz"]].to_numpy()).max() > 1e-3
    states = a.copy()
    meas = a[["t"] + rollout.POSITION + rollout.QUATERNION + rollout.ROTORS]
    got = rollout.score(states, meas, 20, 2, {"r": (hybrid, []), "e": (hummingbird, effects)})
    np.testing.assert_allclose(got["r"][0], got["e"][0], rtol=1e-9, atol=1e-12)
    ra, rb = replay(states, meas, hybrid, [], 0.3), replay(states, meas, hummingbird, effects, 0.3)
    np.testing.assert_allclose(ra[["ex", "ey", "ez"]].to_numpy(), rb[["ex", "ey", "ez"]].to_numpy(), atol=1e-9)


def test_the_simulation_study_flies_a_residual(crazyflie):
    """The study's closed loop (qr.sim.study.fly) with a constant residual is the loop with the catalog's
    body_force_bias + torque_bias, sample for sample."""
    from qr.sim.study import Plant, fly, random_reference

    hybrid = crazyflie.with_changes()
    hybrid.residual = _constant(crazyflie, [0.003, -0.002, 0.005, 1e-5, -2e-5, 5e-6])
    effects = [parse_effect_spec("body_force_bias:bx=0.003,by=-0.002,bz=0.005"),
               parse_effect_spec("torque_bias:tx=1e-5,ty=-2e-5,tz=5e-6")]
    ref = random_reference(np.random.default_rng(0), 4.0)
    a, b, c = fly(ref, Plant(hybrid)).log, fly(ref, Plant(crazyflie, effects)).log, fly(ref, Plant(crazyflie)).log
    np.testing.assert_allclose(a.to_numpy(float), b.to_numpy(float), rtol=1e-9, atol=1e-12)
    assert not np.allclose(a.to_numpy(float), c.to_numpy(float))
