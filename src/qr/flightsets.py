"""What each flight of a data set flies: trajectory type, time scale, payload, controller, height.

Read from a data-set file's ``flown:`` groups (``conf/data/*.yaml``): the one place for the fact, which the
held-out splits (:mod:`qr.holdout`) and the replay read.  The fields: docs/workflow.md "What the flights fly".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

from .errors import QrInputError

DEFAULT_DATA = "data/imrclab_crazyflie.yaml"  # under the shipped config tree (qr.shipped.CONF_DIR)
RANDOM = "random"  # the trajectory type whose flights never repeat one another


@dataclass(frozen=True)
class FlightInfo:
    """What one flight flies (None where the source does not say)."""

    flight: str
    trajectory: str
    time_scale: float | None = None
    segment_s: float | None = None
    axis: str | None = None
    payload_g: float | None = None
    controller: str | None = None
    height: float | None = None
    note: str | None = None

    def trajectory_id(self) -> tuple:
        """Everything but the flight's name and note: flights with the same id repeat one trajectory (a
        ``random`` flight repeats none)."""
        same = tuple(getattr(self, f.name) for f in fields(self) if f.name not in ("flight", "note"))
        return same + ((self.flight,) if self.trajectory == RANDOM else ())

    def describe(self) -> str:
        """Short words for a report: ``figure8 ×0.5``, ``sideways y 1.3 s``."""
        parts = [self.trajectory]
        if self.axis:
            parts.append(self.axis)
        if self.time_scale is not None:
            parts.append(f"×{self.time_scale:g}")
        if self.segment_s is not None:
            parts.append(f"{self.segment_s:g} s")
        return " ".join(parts)


GROUP_KEYS = {f.name for f in fields(FlightInfo)} - {"flight"} | {"flights"}


def _number(where, key, value, positive=True):
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or (positive and value <= 0) or (not positive and value < 0):
        raise QrInputError(where, f"{key}: {value!r} is not a {'positive' if positive else 'non-negative'} number",
                           f"give {key} as a number (or leave it out where the source does not say)")
    return float(value)


def parse_flown(groups, used: list[str] | None = None, where: str = "flown") -> dict[str, FlightInfo]:
    """Flight name -> :class:`FlightInfo` from a set's ``flown:`` list; ``used``: the set's flights, each
    of which must be described exactly once."""
    if not isinstance(groups, list) or not groups:
        raise QrInputError(where, "flown: is not a non-empty list of groups",
                           "give flown: [{flights: [...], trajectory: NAME, ...}, ...]")
    out: dict[str, FlightInfo] = {}
    for k, g in enumerate(groups):
        at = f"{where}[{k}]"
        if not isinstance(g, dict):
            raise QrInputError(at, "a group is not a mapping", "give {flights: [...], trajectory: NAME, ...}")
        extra = sorted(set(g) - GROUP_KEYS)
        if extra:
            raise QrInputError(at, f"unknown key {extra[0]!r}", f"use {', '.join(sorted(GROUP_KEYS))}")
        names, traj = g.get("flights"), g.get("trajectory")
        if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
            raise QrInputError(at, "flights: is not a non-empty list of flight names", "list the group's flights")
        if not isinstance(traj, str) or not traj.strip():
            raise QrInputError(at, "no trajectory name", "give trajectory: figure8 (or the type the source names)")
        axis = g.get("axis")
        if axis is not None and axis not in ("x", "y", "z"):
            raise QrInputError(at, f"axis: {axis!r} is not x, y or z", "give the direction the flight moves along")
        info = dict(trajectory=traj.strip(), time_scale=_number(at, "time_scale", g.get("time_scale")),
                    segment_s=_number(at, "segment_s", g.get("segment_s")), axis=axis,
                    payload_g=_number(at, "payload_g", g.get("payload_g"), positive=False),
                    controller=None if g.get("controller") is None else str(g["controller"]),
                    height=_number(at, "height", g.get("height")),
                    note=None if g.get("note") is None else str(g["note"]))
        for n in names:
            if n in out:
                raise QrInputError(at, f"flight {n} is described twice", "describe each flight in one group")
            out[n] = FlightInfo(flight=n, **info)
    missing = [n for n in used or [] if n not in out]
    if missing:
        raise QrInputError(where, f"flight(s) {', '.join(missing)} of the set are not described",
                           "add them to a group of flown: (or leave flown: out)")
    return out


@dataclass(frozen=True)
class FlightSet:
    """One set of a data-set file: its used flights in order and what each flies (empty: not described)."""

    name: str
    flights: tuple[str, ...]
    infos: dict  # flight -> FlightInfo, every described flight (also those the set does not use)

    @property
    def described(self) -> bool:
        return bool(self.infos)

    def info(self, flight: str) -> FlightInfo:
        name = Path(str(flight)).stem if str(flight) not in self.infos else str(flight)
        if name not in self.infos:
            raise QrInputError(flight, f"set {self.name} does not say what flight {name} flies",
                               f"describe it under the set's flown: in the data-set file")
        return self.infos[name]


def data_file(path: str | Path | None = None) -> Path:
    """A data-set file by path, or the shipped default (``conf/data/imrclab_crazyflie.yaml``)."""
    if path is None or str(path) == "":
        from .shipped import CONF_DIR

        return Path(CONF_DIR) / DEFAULT_DATA
    p = Path(path)
    if not p.is_file():
        from .shipped import CONF_DIR

        shipped = Path(CONF_DIR) / "data" / f"{p.name}.yaml"
        if p.suffix not in (".yaml", ".yml") and shipped.is_file():
            return shipped
        raise QrInputError(path, "data-set file does not exist", "give a conf/data/*.yaml file (or a shipped name)")
    return p


def load_sets(path: str | Path | None = None) -> dict[str, FlightSet]:
    """Every set of a data-set file (its ``flown:`` checked against its flights)."""
    import yaml

    p = data_file(path)
    doc = yaml.safe_load(p.read_text()) or {}
    sets = doc.get("sets")
    if not isinstance(sets, dict) or not sets:
        raise QrInputError(p, "no sets: in the data-set file", "see docs/workflow.md, 'Your own data set'")
    out = {}
    for name, s in sets.items():
        flights = tuple(s.get("flights") or [])
        flown = s.get("flown")
        infos = parse_flown(flown, list(flights), f"{p}: sets.{name}.flown") if flown is not None else {}
        out[name] = FlightSet(name, flights, infos)
    return out


def flight_set(set_name: str, path: str | Path | None = None) -> FlightSet:
    sets = load_sets(path)
    if set_name not in sets:
        raise QrInputError(data_file(path), f"no set {set_name!r} (it has {', '.join(sets)})", "name one of its sets")
    return sets[set_name]


def flight_info(set_name: str, flight: str, path: str | Path | None = None) -> FlightInfo:
    """What ``flight`` (a name, or a file named after it) of ``set_name`` flies (``path``: the data-set
    file, default the shipped Crazyflie one)."""
    return flight_set(set_name, path).info(flight)


def spread(flights, infos: dict[str, FlightInfo] | None, n: int) -> list[str]:
    """``n`` of ``flights`` that differ where they can (a reduced run): the first flight of each trajectory
    type, then of each type's next trajectory, and so on, then second flights; kept in the set's order.
    Without ``infos`` (no ``flown:``): the first ``n``."""
    flights = [str(f) for f in flights]
    if not infos or any(f not in infos for f in flights):
        return flights[:n]
    types = list(dict.fromkeys(infos[f].trajectory for f in flights))
    ids: dict[str, list] = {}
    for f in flights:
        ids.setdefault(infos[f].trajectory, [])
        if infos[f].trajectory_id() not in ids[infos[f].trajectory]:
            ids[infos[f].trajectory].append(infos[f].trajectory_id())
    same = {f: [g for g in flights if infos[g].trajectory_id() == infos[f].trajectory_id()].index(f) for f in flights}

    def rank(f):
        i = infos[f]
        return (same[f], ids[i.trajectory].index(i.trajectory_id()), types.index(i.trajectory))

    chosen = set(sorted(flights, key=rank)[:n])
    return [f for f in flights if f in chosen]
