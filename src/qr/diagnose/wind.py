"""A constant moment that may be the wind's: the named velocity moments in the wind the named wind force implies.

Drag, blade flapping and the rotor drag at the hubs act on the airspeed ``v_b − Rᵀ w``.  The catalog
writes them on the body velocity ``v_b``, so a steady wind ``w`` leaves, beside its force (``wind_force``),
a moment: the velocity moments' terms at ``−Rᵀ w``.  At a held heading that moment is nearly constant in
the body frame, and ``cg_offset`` or ``torque_bias`` fits it: a CG offset would be named for the wind
(RotorPy, whose aerodynamics act on the airspeed, shows it: ``tests/diagnose/test_wind_moment.py``).

:func:`wind_moments` takes the wind the named force terms imply (the horizontal ``w`` for which the
named drags' wind part equals the named ``wind_force``), the moment the named velocity moments give in
it, and compares it with each named constant moment, averaged over the training part: a moment within
``MAX_ANGLE_DEG`` of the wind's direction and ``MAX_RATIO`` of its size either way cannot be told from
the wind's.  That effect is reported ``confounded_with: ["wind_force"]``, with the numbers; it stays in
the model (the moment is real, whatever makes it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..identification.normal_equations import Columns
from .core import predict

VELOCITY_MOMENTS = ("blade_flapping", "rotor_drag_moment")  # torque terms of the body velocity
CONSTANT_MOMENTS = ("cg_offset", "torque_bias")  # what a moment held in the body frame is named as
WIND = "wind_force"
MAX_ANGLE_DEG = 30.0  # the wind's moment and the named one this close in direction (roll/pitch plane)...
MAX_RATIO = 3.0  # ...and in size within this factor either way: the drags named set the wind's size only roughly
STEP = 0.5  # m/s: the finite wind over which the named drags' response is taken (linear drags: exact)
MIN_RESPONSE = 1e-3  # the named drags' horizontal response, relative to their largest one, below which no wind
# can be inferred from the force


@dataclass(frozen=True)
class WindMoment:
    """A named constant moment that the wind the named force implies would make through the named
    velocity moments (world wind in m/s; moments in N m, roll and pitch, averaged over the training part)."""

    effect: str
    wind: tuple[float, float]
    moment_terms: tuple[str, ...]
    wind_moment: tuple[float, float]
    named_moment: tuple[float, float]

    @property
    def angle_deg(self) -> float:
        a, b = np.asarray(self.wind_moment), np.asarray(self.named_moment)
        c = float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))
        return math.degrees(math.acos(min(1.0, max(-1.0, c))))

    @property
    def ratio(self) -> float:
        return float(np.linalg.norm(self.named_moment) / np.linalg.norm(self.wind_moment))

    def sentence(self) -> str:
        wx, wy = self.wind
        (rw, pw), (rn, pn) = self.wind_moment, self.named_moment
        return (f"its moment (roll {rn:.3g}, pitch {pn:.3g} N m on average) is what the named "
                f"{' and '.join(self.moment_terms)} give{'s' * (len(self.moment_terms) == 1)} in the wind the named "
                f"{WIND} implies through the named drag ({wx:.3g}, {wy:.3g} m/s: roll {rw:.3g}, pitch {pw:.3g} N m), "
                f"{self.angle_deg:.0f}° apart, {self.ratio:.2g} x: it may be the wind's moment, not a "
                f"{'CG offset' if self.effect == 'cg_offset' else 'torque on the body'}")

    def record(self) -> dict:
        return {"effect": self.effect, "wind": list(self.wind), "moment_terms": list(self.moment_terms),
                "wind_moment": list(self.wind_moment), "named_moment": list(self.named_moment),
                "angle_deg": self.angle_deg, "ratio": self.ratio}


def _in_wind(s, w: np.ndarray):
    """``s`` with the body velocity replaced by the airspeed in the world wind ``w`` (3,)."""
    return replace(s, v_b=s.v_b - np.einsum("nji,j->ni", s.R, w))


def wind_moments(s, vehicle, named: list[str], theta: np.ndarray) -> tuple[WindMoment, ...]:
    """The named constant moments (``CONSTANT_MOMENTS``) that the wind the named ``wind_force`` implies would
    make through the named velocity moments, on the signals ``s`` (the training part); () where the named set
    lacks one of the three, or no drag named responds to a horizontal wind."""
    moments = [e for e in named if e in VELOCITY_MOMENTS]
    constant = [e for e in named if e in CONSTANT_MOMENTS]
    if WIND not in named or not moments or not constant or not len(s):
        return ()
    cols = Columns.of(named)
    own = [e for e in named if e != WIND]
    th_own = theta[cols.index(own)]
    base = predict(s, vehicle, own, th_own)

    def wind_part(w):
        """Mean world force (x, y) and body moment (roll, pitch) of the named terms' wind part."""
        d = predict(_in_wind(s, w), vehicle, own, th_own) - base
        return np.einsum("nij,nj->ni", s.R, d[:, :3]).mean(0)[:2], d[:, 3:5].mean(0)

    # the wind the named force implies: the named drags' wind force (x, y), linear in w for linear drags
    resp = np.column_stack([wind_part(STEP * np.eye(3)[k])[0] / STEP for k in range(2)])
    if not np.isfinite(resp).all() or abs(np.linalg.det(resp)) <= (MIN_RESPONSE * np.abs(resp).max()) ** 2:
        return ()
    f_w = theta[cols.slices[WIND]][:2]
    w = np.append(np.linalg.solve(resp, f_w), 0.0)
    _, tau_w = wind_part(w)
    if not np.linalg.norm(tau_w) > 0:
        return ()
    out = []
    for e in constant:
        tau_c = predict(s, vehicle, [e], theta[cols.index([e])])[:, 3:5].mean(0)
        if not np.linalg.norm(tau_c) > 0:
            continue
        m = WindMoment(e, (float(w[0]), float(w[1])), tuple(moments), (float(tau_w[0]), float(tau_w[1])),
                       (float(tau_c[0]), float(tau_c[1])))
        if m.angle_deg <= MAX_ANGLE_DEG and 1 / MAX_RATIO <= m.ratio <= MAX_RATIO:
            out.append(m)
    return tuple(out)
