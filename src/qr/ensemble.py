"""A residual ensemble for ``qr learn residual``'s band (``learn.members``; :mod:`qr.bands`).

Each member is a residual trained like the hybrid's own (:func:`qr.residual_fit.train`, same settings and
validation windows) on the training flights *resampled by flight*: as many flights as there are, drawn
with replacement, each drawn flight bringing all of its training windows (a flight drawn twice counts
twice: its windows enter the member's training set twice, it stays one flight); the validation flights
are never drawn.  Member k draws its flights from ``numpy.random.default_rng([seed, k])`` and trains with
seed ``seed + 1 + k``.  A lone flight (validation by time) cannot be resampled by flight: its members
differ by their seeds only, and the band says so.

The files, beside ``hybrid_vehicle.yaml`` (an addition to docs/spec/hybrid.md's outputs; the hybrid
itself is unchanged)::

    members/member1.npz …        each member's weights, the format of residual.npz (qr.mlp/1)
    hybrid_vehicle.bands.json    {"schema": "qr.bands/1", "kind": "ensemble",
                                  "members": [{"residual": <the vehicle key `residual` of that member, its
                                               model relative to this file>, "seed", "flights": {flight: times
                                               drawn}, "best_epoch"}, ...],
                                  "scale": {"p", "v", "R", "w"}, "horizon": H (the h the scale was chosen at),
                                  "calibrated_on": "..."}
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, replace

import numpy as np

MEMBERS_DIR = "members"
BANDS_FILE = "hybrid_vehicle.bands.json"


@dataclass(frozen=True)
class Member:
    residual: object  # qr.residual.Residual
    seed: int
    flights: dict  # flight -> times drawn
    best_epoch: int


def resample(flights: list[str], seed: int, k: int) -> dict:
    """Member ``k``'s draw: ``len(flights)`` flights with replacement, as {flight: times drawn} (in the given
    order, only the drawn ones)."""
    rng = np.random.default_rng([seed, k])
    c = Counter(flights[i] for i in rng.integers(0, len(flights), len(flights)))
    return {f: c[f] for f in flights if c[f]}


def member_pieces(parts: list, draw: dict) -> list:
    """The pieces (:class:`qr.residual_fit.Piece`) member training sees: each piece of a drawn flight with its
    training starts, once per draw (the copies without validation starts); every piece keeps its validation
    starts once."""
    out = []
    for pc in parts:
        n = draw.get(pc.flight, 0)
        out.append(replace(pc, train=pc.train if n else pc.train[:0]))
        out += [replace(pc, val=pc.val[:0]) for _ in range(max(n - 1, 0))]
    return out


def train_members(cfg, vehicle, parts: list, training: list[str], seed: int, members: int,
                  log=lambda m: None) -> list[Member]:
    """``members`` residuals, each on the ``training`` flights resampled by flight (see the module doc)."""
    from .residual_fit import train

    out = []
    for k in range(members):
        draw = resample(training, seed, k)
        log(f"ensemble member {k + 1} of {members}: {sum(draw.values())} flights drawn "
            f"({len(draw)} distinct of {len(training)})")
        t = train(cfg, vehicle, member_pieces(parts, draw), seed + 1 + k, lambda m: None)
        out.append(Member(t.net.to_residual(), seed + 1 + k, draw, t.best_epoch))
    return out


def calibrated(physical, centre, members: list[Member], parts: list, H: int) -> tuple[dict | None, str]:
    """The band's scale per quantity on the validation windows (:func:`qr.bands.calibrate`) and where."""
    from . import bands
    from .sim.plant import true_params

    val = [pc.windows.scored_at(pc.val) for pc in parts if len(pc.val)]
    if len(members) < 2 or not val:
        return None, ""
    rows = [true_params(centre, list(centre.effects))]
    for m in members:
        v = physical.with_changes()
        v.residual = m.residual
        rows.append(true_params(v, list(v.effects)))
    sp = bands.spread(val, np.array(rows), H)
    return bands.calibrate(sp), f"the {len(val)} validation piece(s) of qr learn residual ({len(sp.err)} windows)"


def write(tmp, members: list[Member], scale, where: str, note: str, horizon: int) -> None:
    """``members/`` and ``hybrid_vehicle.bands.json`` into the folder ``tmp`` (being written atomically)."""
    from . import residual as rs
    from .atomic import write_json
    from .bands import SCHEMA

    (tmp / MEMBERS_DIR).mkdir()
    docs = []
    for k, m in enumerate(members, 1):
        name = f"{MEMBERS_DIR}/member{k}.npz"
        rs.save_weights(m.residual, tmp / name)
        docs.append({"residual": rs.block(m.residual, name, f"{note}; ensemble member {k}"), "seed": m.seed,
                     "flights": m.flights, "best_epoch": m.best_epoch})
    write_json(tmp / BANDS_FILE, {"schema": SCHEMA, "kind": "ensemble", "vehicle": "hybrid_vehicle.yaml",
                                  "members": docs, "scale": scale, "horizon": horizon, "calibrated_on": where,
                                  "resampling": "by flight: each member draws as many training flights as there "
                                                "are, with replacement; a flight drawn twice counts twice"})
