"""The two effects that act at the rotor hubs, against closed forms derived by hand.

``rotor_drag_moment`` (the H-force ``-k u_i [w_ix, w_iy, 0]`` at each hub, ``w_i = v_b + ω × r_i``) and
``translational_lift`` (rotor i's thrust ``+ k (w_ix² + w_iy²)``).  For four equal rotor speeds ``u`` on a
symmetric layout (plus or x: ``Σ r_i = 0``, ``Σ x_i y_i = 0``, ``Σ x_i² = Σ y_i² = 2 l²``) with the hubs ``h``
above the CG, expanding the sums by hand (a = v_x + h ω_y, b = v_y − h ω_x)::

    rotor_drag_moment   τ = k u [4 h b, −4 h a, −4 l² ω_z]
    translational_lift  f_z = k (4 (a² + b²) + 4 l² ω_z²),  τ = −4 k l² ω_z [a, b, 0]

The catalog's design (qr.effects: vectorised cross products) and the TRUE plant (qr.sim.plant: a loop over
the hubs in numba) are each held to these numbers, and the plant's residual along a flight with the hubs
above the CG to the catalog term (as tests/simulate/test_effects_in_plant.py does with the hubs in the CG's
plane).
"""

import numpy as np
import pytest

from conftest import signals_from_truth
from qr.dynamics import residuals
from qr.effects import CATALOG, Signals, parse_effect_spec, total_term
from qr.sim.plant import plant_accels, true_params
from qr.sim.synth import SynthConfig, simulate_truth
from qr.sim.trajectory import TrajectoryConfig

H = 0.04  # m, hubs above the CG


def closed_form(name, k, u, l, h, v, w):
    a, b = v[0] + h * w[1], v[1] - h * w[0]
    out = np.zeros(6)
    if name == "rotor_drag_moment":
        out[3:] = k * u * np.array([4 * h * b, -4 * h * a, -4 * l**2 * w[2]])
    else:
        out[2] = k * (4 * (a * a + b * b) + 4 * l**2 * w[2] ** 2)
        out[3:5] = -4 * k * l**2 * w[2] * np.array([a, b])
    return out


def _vehicle(v, layout):
    raw = dict(v.raw, layout=layout, hub_z=H)
    return v.with_changes(**raw)


CASES = [(n, lay) for n in ("rotor_drag_moment", "translational_lift") for lay in ("plus", "x")]


@pytest.mark.parametrize("name,layout", CASES)
def test_catalog_term_and_plant_equal_the_closed_form(name, layout, hummingbird):
    veh = _vehicle(hummingbird, layout)
    l = hummingbird.raw["arm_length"]  # Σ x_i² = Σ y_i² = 2 l² in either layout
    k = 2e-5 if name == "rotor_drag_moment" else 0.02
    rng = np.random.default_rng(4)
    u = veh.hover_speed * 1.1
    for _ in range(5):
        v, w = rng.normal(0, 2, 3), rng.normal(0, 1.5, 3)
        want = closed_form(name, k, u, l, H, v, w)
        # the catalog term, on signals with a level attitude
        s = Signals(R=np.eye(3)[None], v_b=v[None], a_b=np.zeros((1, 3)), omega=w[None], alpha=np.zeros((1, 3)),
                    u=np.full((1, 4), u), u_dot=np.zeros((1, 4)), p=np.array([[0.0, 0.0, 1.0]]))
        term = CATALOG[name].term({"k": k}, s, veh)[0]
        np.testing.assert_allclose(term, want, rtol=1e-12, atol=1e-15)
        # the plant: the same state with and without the effect, the difference in J α and m a_body
        x = np.zeros(17)
        x[2], x[3:6], x[6], x[10:13], x[13:] = 1.0, v, 1.0, w, u
        P1, P0 = true_params(veh, [{"name": name, "parameters": {"k": k}}]), true_params(veh, [])
        zero = np.zeros(3)
        a1, al1 = plant_accels(x, x[13:], P1, zero, zero)
        a0, al0 = plant_accels(x, x[13:], P0, zero, zero)
        got = np.concatenate([veh.mass * (a1 - a0), veh.inertia * (al1 - al0)])
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)
    assert np.abs(want).max() > 1e-4  # the effect is there


def test_hubs_in_the_cg_plane_make_rotor_drag_moment_a_pure_yaw_damping(hummingbird):
    s = Signals(R=np.eye(3)[None], v_b=np.array([[1.0, -2.0, 0.5]]), a_b=np.zeros((1, 3)),
                omega=np.array([[0.3, -0.2, 0.7]]), alpha=np.zeros((1, 3)), u=np.full((1, 4), 5000.0),
                u_dot=np.zeros((1, 4)), p=np.array([[0.0, 0.0, 1.0]]))
    term = CATALOG["rotor_drag_moment"].term({"k": 1e-5}, s, hummingbird)[0]
    l = hummingbird.raw["arm_length"]
    np.testing.assert_allclose(term, [0, 0, 0, 0, 0, -1e-5 * 5000 * 4 * l**2 * 0.7], atol=1e-15)


@pytest.mark.parametrize("name,spec", [("rotor_drag_moment", "k=2e-5"), ("translational_lift", "k=0.02")])
def test_plant_residual_with_hubs_above_the_cg_is_the_catalog_term(name, spec, hummingbird):
    veh = _vehicle(hummingbird, "plus")
    effect = parse_effect_spec(f"{name}:{spec}")
    truth = simulate_truth(veh, [effect], SynthConfig(duration=10, seed=3, noise_free=True,
                                                      trajectory=TrajectoryConfig()))
    s = signals_from_truth(truth)
    r, term = residuals(s, veh), total_term([effect], s, veh)
    assert np.abs(term[:, 3:5]).max() > 1e-4  # the hubs' height gives roll and pitch moments
    np.testing.assert_allclose(r, term, atol=1e-10)


def test_hub_z_is_checked(hummingbird, tmp_path):
    from qr.errors import QrInputError

    with pytest.raises(QrInputError, match="hub_z"):
        hummingbird.with_changes(hub_z=40.0)  # millimetres given as metres
    assert hummingbird.hub_z == 0.0 and _vehicle(hummingbird, "plus").hub_z == H
