"""The learned terms of a hybrid vehicle as the exports carry them: the network in NumPy, its weights beside.

A hybrid (``qr learn residual``, docs/spec/hybrid.md) carries a learned body wrench, an MLP
(:mod:`qr.residual`), and may carry a learned torque remainder (:mod:`qr.torque_remainder`).  The
RotorPy module and the MuJoCo helper module an export writes evaluate them with NumPy alone (no torch,
no qr): the weights are copied beside them in qr's own ``qr.mlp/1`` format (``W0, b0, …``), the
scaling written into the module with every digit, rotor speeds rescaled to rad/s.
"""

from __future__ import annotations

import numpy as np

from ..residual import weights_bytes
from . import mapping as mp
from .mapping import File


class Exact(list):
    """Numbers written with every digit (a network's scaling: 10 digits would change its output)."""

    def __init__(self, xs):
        super().__init__(float(x) for x in np.ravel(xs))


class Verbatim(str):
    """Python source written as is."""


def residual_file(stem: str) -> str:
    """The learned wrench's weights beside the exported module."""
    return f"{stem}_residual.npz"


def residual_spec(vehicle, pp: mp.Plant, stem: str) -> dict | None:
    """The learned wrench as the exported module evaluates it (None without one): its input groups in φ's
    order, the activation, the scaling (rotor speeds in rad/s) and the weights' file."""
    net = vehicle.residual
    if net is None:
        return None
    return {"model": residual_file(stem), "inputs": Verbatim(repr(list(net.inputs))),
            "activation": Verbatim(repr(net.activation)),
            "rotor_speed_scale": Exact([net.rotor_speed_scale * pp.unit]), "input_mean": Exact(net.input_mean),
            "input_scale": Exact(net.input_scale), "output_scale": Exact(net.output_scale)}


def weights(vehicle, stem: str) -> list[File]:
    """The network's ``.npz`` beside the exported module (nothing without one)."""
    if vehicle.residual is None:
        return []
    return [File(residual_file(stem), weights_bytes(vehicle.residual))]


def literal(x, number) -> str:
    """Python source of ``x``: dicts, lists (as arrays), ``Exact`` and ``Verbatim`` values, numbers by ``number``."""
    if x is None:
        return "None"
    if isinstance(x, Verbatim):
        return str(x)
    if isinstance(x, Exact):
        return repr(x[0]) if len(x) == 1 else "np.array([" + ", ".join(repr(v) for v in x) + "], float)"
    if isinstance(x, str):
        return repr(x)
    if isinstance(x, dict):
        return "{" + ", ".join(f"'{k}': {literal(v, number)}" for k, v in x.items()) + "}"
    if isinstance(x, (list, tuple)):
        if x and isinstance(x[0], (list, tuple)):
            return "[" + ", ".join(literal(v, number) for v in x) + "]"
        return "np.array([" + ", ".join(number(v) for v in np.ravel(x)) + "], float)"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    return number(x)


# The learned terms in NumPy, as the exported modules hold them (module globals: ``RESIDUAL``, the dict of
# residual_spec or None; ``REMAINDER``, the torque remainder's W (3 x 11) or None; ``REMAINDER_HOVER_SPEED``, rad/s).
LEARNED_SOURCE = '''
def _load_network(spec):
    """The learned wrench's layers [(W, b), ...] from its .npz beside this module (None without one)."""
    if spec is None:
        return None
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), spec["model"])
    with np.load(path, allow_pickle=False) as z:
        return [(np.asarray(z[f"W{k}"], float), np.asarray(z[f"b{k}"], float)) for k in range(len(z.files) // 2)]


NETWORK = _load_network(RESIDUAL)


def residual_wrench(v_b, omega, g_b, rotor_speeds):
    """The network's body force (N) and torque (N m) at the CG, body frame: qr's network (qr.residual) in NumPy,
    from the CG's velocity in the body frame, the body rate, the gravity direction in the body frame
    (R^T [0, 0, -1]) and the rotor speeds (rad/s)."""
    s = np.asarray(rotor_speeds, float) / RESIDUAL["rotor_speed_scale"]
    groups = {"v_b": v_b, "omega": omega, "g_b": g_b, "u": s, "u2": s * s}
    z = np.concatenate([np.asarray(groups[k], float) for k in RESIDUAL["inputs"]])
    z = (z - RESIDUAL["input_mean"]) / RESIDUAL["input_scale"]
    for k, (W, b) in enumerate(NETWORK):
        z = W @ z + b
        if k < len(NETWORK) - 1:
            z = np.tanh(z) if RESIDUAL["activation"] == "tanh" else np.maximum(z, 0.0)
    w = z * RESIDUAL["output_scale"]
    return w[:3], w[3:]


def learned_wrench(v_b, omega, g_b, rotor_speeds):
    """Body force (N) and torque (N m) at the CG of every learned term: the torque remainder
    W [v_b, omega, (omega_i / omega_hover)^2 - 1, 1] (qr.torque_remainder) and the network."""
    force, torque = np.zeros(3), np.zeros(3)
    if REMAINDER is not None:
        speeds = np.asarray(rotor_speeds, float)
        torque += REMAINDER @ np.concatenate([v_b, omega, (speeds / REMAINDER_HOVER_SPEED) ** 2 - 1.0, [1.0]])
    if NETWORK is not None:
        f, t = residual_wrench(v_b, omega, g_b, rotor_speeds)
        force += f
        torque += t
    return force, torque
'''
