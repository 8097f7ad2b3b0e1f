"""The plant's two vectors, every slot named once: the state ``x`` and the parameter vector ``P``.

The compiled plant (:mod:`qr.sim.plant` and the kernels that fly it: :mod:`qr.rollout`, :mod:`qr.bands`,
the refinement, the replay, the study) and its torch twin (:mod:`qr.rollout_torch`) index both vectors
by these names only.  A slot of one value is named by its index (an ``int``), a longer one by its
``slice``; ``P[P_LIN]`` is the linear drag's three coefficients, ``P[P_LIN.start + 1]`` the one along body
y.  numba reads module-level ints and slices as compile-time constants, so the names cost nothing in the
compiled loops; after changing a layout, delete numba's on-disk cache (``find src -name '*.nb*' -delete``):
it does not see a change in another module.

Slots are declared in order, each right after the last (:class:`Layout`), so the layout has no gap and
no overlap; ``tests/core/test_plant_state.py`` checks that every name of this module is one slot.  The
Python side reads and writes a vector through its frozen view (:func:`unpack`, :func:`pack`).
"""

from __future__ import annotations

from dataclasses import astuple, dataclass, make_dataclass

import numpy as np


@dataclass(frozen=True)
class Slot:
    name: str  # the view's field
    offset: int
    length: int
    doc: str

    @property
    def index(self) -> int | slice:
        """What indexes the slot in a vector: its offset (one value) or its slice."""
        return self.offset if self.length == 1 else slice(self.offset, self.offset + self.length)


class Layout:
    """A vector's slots, each declared right after the last, and its frozen view (a dataclass with one field
    per slot: a ``float`` for one value, an array for more)."""

    def __init__(self, name: str):
        self.name = name
        self.slots: list[Slot] = []
        self._view = None

    @property
    def size(self) -> int:
        return sum(s.length for s in self.slots)

    def slot(self, name: str, length: int = 1, doc: str = "") -> int | slice:
        self.slots.append(Slot(name, self.size, length, doc))
        return self.slots[-1].index

    def view(self) -> type:
        if self._view is None:
            self._view = make_dataclass(self.name, [(s.name, float if s.length == 1 else np.ndarray)
                                                    for s in self.slots], frozen=True)
            self._view.__doc__ = f"The {self.name} vector by slot: " + "; ".join(
                f"{s.name} ({s.length})" + (f": {s.doc}" if s.doc else "") for s in self.slots)
        return self._view


# ---- the state x of the TRUE plant (qr.sim.plant) ------------------------------------------------
STATE = Layout("PlantState")
X_POS = STATE.slot("position", 3, "m, world, of the CG (of the tracked point in a rollout's start and output rows)")
X_VEL = STATE.slot("velocity", 3, "m/s, world")
X_QUAT = STATE.slot("quaternion", 4, "body to world, scalar first")
X_RATE = STATE.slot("rate", 3, "rad/s, body")
N_RB = STATE.size  # the rigid body's p, v, q, ω: what a rollout integrates and each of its rows holds
X_ROTORS = STATE.slot("rotor_speeds", 4, "the vehicle's rotor-speed unit (first-order motor lag)")
N_X = STATE.size
STATE_PARTS = tuple(s.length for s in STATE.slots[:4])  # p, v, q, ω: a rigid-body state split by slot

# ---- the parameter vector P of the TRUE plant: the vehicle and its catalog effects (qr.sim.plant.true_params)
PARAMS = Layout("PlantParams")
P_MASS = PARAMS.slot("mass", 1, "kg")
P_J = PARAMS.slot("inertia", 3, "kg m², the principal moments")
P_B = PARAMS.slot("rotor_matrix", 16, "u² → thrust, roll, pitch, yaw torque (4 x 4, row by row)")
P_SCALE = PARAMS.slot("thrust_scale", 4, "per-rotor thrust factor (thrust_gain, motor_imbalance)")
P_CQGAIN = PARAMS.slot("yaw_torque_gain", 1, "factor on every rotor's yaw torque")
P_TAU = PARAMS.slot("motor_time_constant", 1, "s")
P_DELAY = PARAMS.slot("actuator_delay", 1, "s")
P_LIN = PARAMS.slot("linear_drag", 3, "N s/m, body")
P_QUAD = PARAMS.slot("quadratic_drag", 3, "N s²/m², body")
P_RDRAG = PARAMS.slot("rotor_drag", 1, "N s/m per rotor-speed unit")
P_WIND = PARAMS.slot("wind_force", 3, "N, world")
P_BBIAS = PARAMS.slot("body_force_bias", 3, "N, body")
P_GE = PARAMS.slot("ground_effect", 1, "m²")
P_GZ = PARAMS.slot("ground_z", 1, "m, the floor's height")
P_CG = PARAMS.slot("cg_offset", 2, "m, body x, y")
P_TBIAS = PARAMS.slot("torque_bias", 3, "N m, body")
P_FLAP = PARAMS.slot("blade_flapping", 1, "N m s/m")
P_MARKER = PARAMS.slot("marker_offset", 3, "m, the tracked point from the CG, body")
P_REM_ON = PARAMS.slot("remainder_on", 1, "1: a learned torque remainder (qr.torque_remainder)")
P_UHOVER = PARAMS.slot("hover_speed", 1, "the remainder's u_hover, rotor-speed unit")
P_REM = PARAMS.slot("remainder", 33, "the remainder's W (3 x 11, row by row)")
P_RES_ON = PARAMS.slot("residual_on", 1, "1: a learned wrench (qr.residual), its network at P[N_P:]")
P_RDM = PARAMS.slot("rotor_drag_moment", 1, "k, N s/m per rotor-speed unit, at the hubs")
P_TLIFT = PARAMS.slot("translational_lift", 1, "k, N s²/m² per rotor, at the hubs")
P_HUB = PARAMS.slot("hubs", 12, "m, each rotor's hub (x, y, z) from the layout's centre, rotor by rotor")
# rotor and airframe properties the catalog has no term for (qr.vehicle.ROTOR_PROPERTIES)
P_FLAP_PITCH = PARAMS.slot("flapping_pitch_ratio", 1, "the blade-flapping coefficient about y over the one about x")
P_ROTOR_J = PARAMS.slot("rotor_inertia", 1, "kg m² times rad/s per rotor-speed unit")
P_YAW_GAIN = PARAMS.slot("rotor_yaw_gains", 4, "each rotor's yaw-torque gain (rotor_torque_gains, motor_imbalance)")
N_P = PARAMS.size

# ---- the learned wrench's network, packed after N_P (qr.residual.pack): its header, then d_0 … d_L, μ, σ,
# the layers' weights and biases, the output scale (offsets from N_P)
NET = Layout("NetworkHeader")
NET_INPUTS = NET.slot("inputs", 5, "1 where the feature group is an input (qr.residual.ORDER)")
NET_SPEED = NET.slot("rotor_speed_scale", 1, "rotor-speed unit")
NET_RELU = NET.slot("activation", 1, "0 tanh, 1 relu")
NET_DEPTH = NET.slot("depth", 1, "the number of layers L")
N_NET_HEAD = NET.size  # d_0 … d_L follow

PlantState, PlantParams = STATE.view(), PARAMS.view()  # the frozen views (types for annotations)


def unpack(vector: np.ndarray, layout: Layout = PARAMS):
    """The frozen view of ``vector``'s slots (a parameter vector's network tail is not in it)."""
    v = np.asarray(vector, float)
    if len(v) < layout.size:
        raise ValueError(f"a {layout.name} vector has {layout.size} values, not {len(v)}")
    return layout.view()(*(float(v[s.offset]) if s.length == 1 else v[s.index].copy() for s in layout.slots))


def pack(view) -> np.ndarray:
    """The vector of a view made by :func:`unpack` (its slots in order)."""
    return np.concatenate([np.atleast_1d(np.asarray(x, float)) for x in astuple(view)])

