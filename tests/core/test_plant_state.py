"""The plant's named vectors (qr.plant_state): every slot declared once, no gap, no overlap, and each name
at the place the plant reads it.

Independent expectations: the state is p (3), v (3), q (4), ω (3), u (4); a catalog effect's parameters,
packed by ``true_params``, come back under the slot named for the effect; the network's header, packed by
``qr.residual.pack``, comes back under its slot names.
"""

from dataclasses import FrozenInstanceError

import numpy as np
import pytest

from qr import plant_state as ps
from qr.effects import parse_effect_spec
from qr.sim.plant import true_params

PREFIXES = {"X_": ps.STATE, "P_": ps.PARAMS, "NET_": ps.NET}


def _names(prefix):
    return {n: getattr(ps, n) for n in dir(ps) if n.startswith(prefix) and isinstance(getattr(ps, n), (int, slice))}


@pytest.mark.parametrize("prefix", PREFIXES)
def test_every_name_is_one_slot_and_the_slots_tile_the_vector(prefix):
    layout = PREFIXES[prefix]
    names = _names(prefix)
    assert len(names) == len(layout.slots)  # no name outside the layout, no slot without a name
    cover = np.zeros(layout.size, int)
    for index in names.values():
        if isinstance(index, slice):
            assert index.step is None and index.stop - index.start > 1
        cover[index] += 1
    assert np.all(cover == 1)  # no gap, no overlap
    span = lambda i: (i, i + 1) if isinstance(i, int) else (i.start, i.stop)  # noqa: E731
    assert sorted(span(i) for i in names.values()) == [(s.offset, s.offset + s.length) for s in layout.slots]


def test_the_state_is_position_velocity_quaternion_rate_rotors():
    assert [(s.name, s.length) for s in ps.STATE.slots] == [("position", 3), ("velocity", 3), ("quaternion", 4),
                                                           ("rate", 3), ("rotor_speeds", 4)]
    assert (ps.N_RB, ps.N_X, ps.STATE_PARTS) == (13, 17, (3, 3, 4, 3))
    assert ps.X_QUAT == slice(6, 10) and ps.X_ROTORS == slice(13, 17)
    x = np.arange(17.0) / 7
    view = ps.unpack(x, ps.STATE)
    assert isinstance(view, ps.PlantState) and view.quaternion.tolist() == x[6:10].tolist()
    assert ps.pack(view).tobytes() == x.tobytes()


EFFECTS = {"linear_drag": "kx=0.3,ky=0.2,kz=0.1", "wind_force": "fx=0.5,fy=-0.3,fz=0.2",
           "body_force_bias": "bx=0.1,by=-0.2,bz=0.3", "cg_offset": "rx=0.01,ry=-0.005",
           "torque_bias": "tx=0.01,ty=-0.01,tz=0.005", "marker_offset": "rx=0.02,ry=-0.01,rz=0.03",
           "quadratic_drag": "cx=0.1,cy=0.15,cz=0.05", "rotor_drag": "k=1e-5", "ground_effect": "k=0.005",
           "blade_flapping": "k=0.02", "actuator_delay": "delay_s=0.025", "rotor_drag_moment": "k=2e-5",
           "translational_lift": "k=0.01"}


def test_each_effect_comes_back_under_its_own_name_and_pack_unpack_round_trips(hummingbird):
    effects = [parse_effect_spec(f"{k}:{p}") for k, p in EFFECTS.items()]
    P = true_params(hummingbird, effects)
    view = ps.unpack(P)
    for e in effects:
        assert np.array_equal(np.atleast_1d(getattr(view, e["name"])), list(e["parameters"].values())), e["name"]
    assert view.mass == hummingbird.mass and np.array_equal(view.inertia, hummingbird.inertia)
    assert np.array_equal(view.rotor_matrix.reshape(4, 4), hummingbird.rotors.matrix)
    assert np.array_equal(view.hubs.reshape(4, 3)[:, :2], hummingbird.rotors.positions[:4])
    assert view.thrust_scale.tolist() == [1.0] * 4 and view.remainder_on == view.residual_on == 0.0
    back = ps.pack(view)
    assert back.dtype == float and back.tobytes() == P[:ps.N_P].tobytes()
    with pytest.raises(FrozenInstanceError):
        view.mass = 1.0
    with pytest.raises(ValueError, match="107 values"):
        ps.unpack(P[:10])


def test_the_network_header_is_where_the_plant_reads_it(hummingbird):
    from qr import residual as rs

    rng = np.random.default_rng(0)
    inputs = ("v_b", "g_b", "u2")
    n = sum(rs.GROUPS[g] for g in inputs)
    res = rs.Residual(inputs, "relu", (rng.normal(size=(8, n)), rng.normal(size=(6, 8))), (np.zeros(8), np.zeros(6)),
                      np.zeros(n), np.ones(n), np.ones(6), 2500.0)
    P = true_params(hummingbird)
    hybrid = hummingbird.with_changes()
    hybrid.residual = res
    Ph = true_params(hybrid)
    assert Ph[:ps.N_P].tobytes() != P.tobytes() and Ph[ps.P_RES_ON] == 1.0
    head = ps.unpack(Ph[ps.N_P:], ps.NET)
    assert head.inputs.tolist() == [float(g in inputs) for g in rs.ORDER]
    assert (head.rotor_speed_scale, head.activation, head.depth) == (2500.0, 1.0, 2.0)
    assert Ph[ps.N_P + ps.N_NET_HEAD:ps.N_P + ps.N_NET_HEAD + 3].tolist() == [n, 8, 6]  # d_0 … d_L
