"""Which flights train and which are scored: ``evaluate.split`` (docs/evaluate.md, "Held-out splits").

``repeat`` (every third flight: interpolation), ``trajectory`` (whole trajectory types or time scales) or
``speed`` (the faster time scales: extrapolation), by what each flight flies (:mod:`qr.flightsets`); the
validation flights are drawn from the training side only, so a scored flight is never opened.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

from .allowed import check_fields, setting, show
from .errors import QrInputError
from .flightsets import FlightInfo

KINDS = ("repeat", "trajectory", "speed")
DEFAULTS_FILE = "src/qr/holdout.py"
REPEAT_TEXT = "every third flight (same trajectories)"


def _kinds() -> list[str]:
    return list(KINDS)


@dataclass
class SplitConfig:
    """``evaluate.split``: which flights the held-out protocol scores (see the module's text)."""

    KEY: ClassVar[str] = "evaluate.split"
    kind: str = setting("repeat", "one", names=_kinds)  # repeat | trajectory | speed
    trajectories: list[str] = field(default_factory=list)  # trajectory: the trajectory types scored
    time_scales: list[float] = field(default_factory=list)  # trajectory: the time scales scored; speed: the faster ones
    data: str = ""  # the data-set file saying what each flight flies (empty: the shipped Crazyflie file)
    set: str = ""  # its set the flights belong to (needed by trajectory and speed)

    def __post_init__(self):
        check_fields(self, lambda name: f"{self.KEY}.{name}", DEFAULTS_FILE)
        self.trajectories = [str(t) for t in (self.trajectories or [])]
        scales = list(self.time_scales or [])
        for x in scales:
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) or x <= 0:
                raise QrInputError(f"{self.KEY}.time_scales", f"{show(x)} is not a positive number",
                                   f"give {self.KEY}.time_scales=[0.5] (the source's TIMESCALE values)")
        self.time_scales = [float(x) for x in scales]
        if self.kind == "repeat" and (self.trajectories or self.time_scales):
            raise QrInputError(f"{self.KEY}.kind", "the repeat split holds out every third flight, not named ones",
                               f"give {self.KEY}.kind=trajectory to hold out what you named")
        if self.kind == "trajectory" and bool(self.trajectories) == bool(self.time_scales):
            raise QrInputError(f"{self.KEY}", "a trajectory split holds out trajectory types or time scales: "
                               + ("both given" if self.trajectories else "neither given"),
                               f"give {self.KEY}.trajectories=[NAME] or {self.KEY}.time_scales=[SCALE]")
        if self.kind == "speed" and self.trajectories:
            raise QrInputError(f"{self.KEY}.trajectories", "a speed split holds out time scales, not trajectories",
                               f"give {self.KEY}.time_scales=[...] (or none: the fastest third)")

    @classmethod
    def from_dict(cls, d) -> "SplitConfig":
        from .allowed import check_known

        d = dict(d or {})
        check_known(cls.KEY, d, cls, DEFAULTS_FILE)
        return cls(**d)

    def infos(self, flights) -> dict[str, FlightInfo] | None:
        """What each of ``flights`` flies (None for ``repeat`` without a set: it needs nothing)."""
        if self.kind == "repeat" and not self.set:
            return None
        if not self.set:
            raise QrInputError(f"{self.KEY}.set", f"a {self.kind} split needs to know what the flights fly",
                               f"give {self.KEY}.set=NAME (and {self.KEY}.data=conf/data/FILE.yaml)")
        from .flightsets import flight_set

        fs = flight_set(self.set, self.data or None)
        return {str(f): fs.info(f) for f in flights}


@dataclass(frozen=True)
class Assignment:
    """A split of a set's flights: ``train`` and ``test`` (scored), in the set's order; ``unused``: neither."""

    kind: str
    train: tuple[str, ...]
    test: tuple[str, ...]
    unused: tuple[str, ...]
    held_out: str  # what is scored, in words ("time scale 0.5", "sideways", "every third flight (same trajectories)")

    def to_dict(self) -> dict:
        return {"kind": self.kind, "held_out": self.held_out, "train": list(self.train), "test": list(self.test),
                "unused": list(self.unused)}


def _scale(x: float) -> str:
    return f"{x:g}"


def _infos_for(flights, infos):
    missing = [f for f in flights if f not in infos]
    if missing:
        raise QrInputError(missing[0], "the split does not know what this flight flies",
                           "describe it under its set's flown: in the data-set file")
    return {f: infos[f] for f in flights}


def assign(flights, split: SplitConfig, infos: dict[str, FlightInfo] | None = None,
           require: bool = True) -> Assignment:
    """Train and test flights of ``flights`` under ``split`` (``infos``: what each flies; default read from
    ``split.data`` / ``split.set``); ``require``: refuse a split that leaves nothing to train on or to score."""
    flights = [str(f) for f in flights]
    if len(set(flights)) < len(flights):
        raise QrInputError(next(f for f in flights if flights.count(f) > 1), "the same flight is given twice",
                           "give each flight once")
    if split.kind == "repeat":
        test = flights[2::3] if len(flights) >= 3 else flights[-1:]
        train = [f for f in flights if f not in test]
        if require and not train:
            raise QrInputError(flights[0] if flights else None, "one flight cannot be held out by flight",
                               "give two flights or more")
        if infos is None and split.set:
            infos = split.infos(flights)
        return Assignment("repeat", tuple(train), tuple(test), (), _repeat_text(train, test, infos))
    info = _infos_for(flights, infos if infos is not None else split.infos(flights))
    if split.kind == "trajectory":
        if split.trajectories:
            known = sorted({i.trajectory for i in info.values()})
            absent = [t for t in split.trajectories if t not in known]
            if absent:
                raise QrInputError(f"{SplitConfig.KEY}.trajectories", f"no flight flies {absent[0]!r}",
                                   f"hold out one of {', '.join(known)}")
            out = lambda i: i.trajectory in split.trajectories  # noqa: E731
            what = ", ".join(split.trajectories)
        else:
            known = sorted({i.time_scale for i in info.values() if i.time_scale is not None})
            absent = [s for s in split.time_scales if s not in known]
            if absent:
                raise QrInputError(f"{SplitConfig.KEY}.time_scales", f"no flight has time scale {_scale(absent[0])}",
                                   f"hold out one of {', '.join(map(_scale, known))}")
            out = lambda i: i.time_scale in split.time_scales  # noqa: E731
            what = f"time scale{'s' * (len(split.time_scales) > 1)} {', '.join(map(_scale, split.time_scales))}"
        test = [f for f in flights if out(info[f])]
        unused: list[str] = []
    else:
        test, unused, what = _speed(flights, info, split)
    train = [f for f in flights if f not in test and f not in unused]
    if require and (not train or not test):
        raise QrInputError(f"{SplitConfig.KEY}", f"the {split.kind} split ({what}) leaves "
                           + ("nothing to train on" if not train else "nothing to score"),
                           "hold out less (or something the set flies)")
    return Assignment(split.kind, tuple(train), tuple(test), tuple(unused), what)


def _repeat_text(train, test, infos) -> str:
    """What the repeat split scores, in words: whether its flights repeat training trajectories (said only
    where the flights are described)."""
    if not infos or any(f not in infos for f in [*train, *test]):
        return "every third flight"
    ids = {infos[f].trajectory_id() for f in train}
    types = {infos[f].trajectory for f in train}
    same = sum(infos[f].trajectory_id() in ids for f in test)
    if same == len(test):
        return REPEAT_TEXT
    typed = sum(infos[f].trajectory in types for f in test)
    return (f"every third flight ({same} of {len(test)} repeat a training trajectory, {typed} of {len(test)} "
            "fly a trained trajectory type)")


def _speed(flights, info, split):
    """Per trajectory type: its time scales in ``split.time_scales`` (default its fastest third) scored,
    every one of them faster than each of its training scales."""
    unused = [f for f in flights if info[f].time_scale is None]
    by_type: dict[str, list[float]] = {}
    for f in flights:
        i = info[f]
        if i.time_scale is not None and i.time_scale not in by_type.setdefault(i.trajectory, []):
            by_type[i.trajectory].append(i.time_scale)
    scored: dict[str, set] = {}
    for t, scales in by_type.items():
        scales = sorted(scales)
        if split.time_scales:
            held = {s for s in scales if s in split.time_scales}
        else:
            held = set(scales[:max(1, len(scales) // 3)]) if len(scales) > 1 else set()
        kept = [s for s in scales if s not in held]
        if held and kept and max(held) >= min(kept):
            raise QrInputError(f"{SplitConfig.KEY}.time_scales", f"{t}: scoring time scale {_scale(max(held))} "
                               f"while training on {_scale(min(kept))} is no extrapolation to faster flights",
                               "hold out the fastest (smallest) time scales of each trajectory")
        scored[t] = held
    if split.time_scales and by_type:
        have = {s for v in by_type.values() for s in v}
        absent = [s for s in split.time_scales if s not in have]
        if absent:
            raise QrInputError(f"{SplitConfig.KEY}.time_scales", f"no flight has time scale {_scale(absent[0])}",
                               f"hold out some of {', '.join(map(_scale, sorted(have)))}")
    test = [f for f in flights if info[f].time_scale is not None and info[f].time_scale in scored[info[f].trajectory]]
    held = sorted({info[f].time_scale for f in test}, reverse=True)
    kept = sorted({info[f].time_scale for f in flights if f not in test and f not in unused}, reverse=True)
    what = (f"time scale{'s' * (len(held) > 1)} {', '.join(map(_scale, held))} (faster), trained on "
            f"{', '.join(map(_scale, kept))}")
    return test, unused, what


def named(info: FlightInfo, split: SplitConfig) -> bool:
    """Whether ``split`` names what this flight flies as scored (a held-out trajectory type or time scale)."""
    return (split.kind != "repeat" and (info.trajectory in split.trajectories
                                         or (info.time_scale is not None and info.time_scale in split.time_scales)))


def validation(train, split: SplitConfig, fraction: float, infos: dict[str, FlightInfo] | None = None) \
        -> tuple[list[str], list[str], str]:
    """(fitting flights, validation flights, how chosen) among the training flights ``train`` only.

    ``repeat`` (or a lone flight): every ``round(1/fraction)``-th flight (at least one; a lone flight:
    none here, its last time block validates, :func:`qr.residual_fit.split`); ``trajectory`` / ``speed``:
    whole trajectories (flights of one :meth:`~qr.flightsets.FlightInfo.trajectory_id`), every k-th
    distinct one in the set's order, at least one, when the training side flies two or more."""
    train = [str(f) for f in train]
    k = max(2, int(round(1 / fraction)))
    if len(train) < 2:
        return train, [], "time"
    if split.kind != "repeat":
        info = _infos_for(train, infos if infos is not None else split.infos(train))
        ids = list(dict.fromkeys(info[f].trajectory_id() for f in train))
        if len(ids) >= 2:
            val_ids = set(ids[k - 1::k] or ids[-1:])
            val = [f for f in train if info[f].trajectory_id() in val_ids]
            return [f for f in train if f not in val], val, "trajectory"
    val = train[k - 1::k] or train[-1:]
    return [f for f in train if f not in val], val, "flight"


def held_out(flights, split: SplitConfig | None = None, require: bool = True) -> Assignment:
    """The held-out protocol's :class:`Assignment` of ``flights`` under ``split`` (``evaluate.split``;
    default ``repeat``: every third flight)."""
    return assign([str(f) for f in flights], split or SplitConfig(), require=require)


def held_out_by_flight(flights: list[str]) -> tuple[list[str], list[str]]:
    """(training, held-out) flights of the repeat split: every third flight held out (the last one of fewer
    than three)."""
    a = held_out(flights, require=False)
    return list(a.train), list(a.test)


def describe(assignment: Assignment, infos: dict[str, FlightInfo] | None) -> str:
    """One line: what trains and what is scored (for reports)."""
    if assignment.kind == "repeat" or not infos:
        return (f"{len(assignment.test)} of {len(assignment.train) + len(assignment.test)} flights scored, "
                f"{assignment.held_out}")

    def kinds(fl):
        return ", ".join(dict.fromkeys(infos[f].describe() for f in fl if f in infos))

    return (f"scored: {len(assignment.test)} flights ({kinds(assignment.test)}); trained on {len(assignment.train)} "
            f"({kinds(assignment.train)})")


# ---- the workflow's folds: the held-out splits it runs per set (conf/data/*.yaml, workflow.generalization) ----

EACH = ("time_scale", "trajectory")
FOLD_KEYS = ("kind", "trajectories", "time_scales", "each", "hybrid")


@dataclass(frozen=True)
class Fold:
    """One held-out split the workflow trains and scores: its name (a folder), the split, whether a residual is
    trained through the rollout for it, and the group of folds it belongs to (``each``: one fold per value,
    pooled in the table)."""

    name: str
    split: SplitConfig
    hybrid: bool
    group: str | None = None

    def to_dict(self) -> dict:
        return {"name": self.name, "kind": self.split.kind, "trajectories": list(self.split.trajectories),
                "time_scales": list(self.split.time_scales), "data": self.split.data, "set": self.split.set,
                "hybrid": self.hybrid, "group": self.group}

    @classmethod
    def from_dict(cls, d: dict) -> "Fold":
        split = SplitConfig(kind=d["kind"], trajectories=list(d.get("trajectories") or []),
                            time_scales=list(d.get("time_scales") or []), data=d.get("data", ""), set=d.get("set", ""))
        return cls(d["name"], split, bool(d.get("hybrid")), d.get("group"))


def fold_name(split: SplitConfig) -> str:
    """A folder name saying what the split scores: ``trajectory-sideways``, ``trajectory-ts0.5``,
    ``speed-ts0.6-0.5``, ``speed-fastest``."""
    what = "-".join(split.trajectories) or ("ts" + "-".join(map(_scale, split.time_scales)) if split.time_scales
                                            else "fastest")
    return f"{split.kind}-{what}"


def folds(specs, flights, data: str, set_name: str, infos: dict[str, FlightInfo] | None = None,
          skipped: list | None = None) -> list[Fold]:
    """The folds of one set from its list of specs (``{kind, trajectories | time_scales | each, hybrid}``;
    ``each: time_scale`` / ``each: trajectory``: one trajectory fold per time scale / type the set's flights
    fly), each checked on ``flights`` (it must leave something to train on and to score).  ``skipped``: a
    list that receives ``(name, reason)`` of each fold these flights cannot make (a run on a subset of the
    set), instead of the error."""
    flights = [str(f) for f in flights]
    out: list[Fold] = []
    if specs and infos is None:  # a set whose flights are not described cannot be split by what they fly
        from .flightsets import flight_set

        fs = flight_set(set_name, data or None)
        infos = {f: fs.info(f) for f in flights}
    for k, spec in enumerate(specs or []):
        where = f"generalization.sets.{set_name}[{k}]"
        if not isinstance(spec, dict) or set(spec) - set(FOLD_KEYS):
            raise QrInputError(where, f"not a fold ({sorted(set(spec) - set(FOLD_KEYS)) if isinstance(spec, dict) else spec})",
                               f"give a mapping of {', '.join(FOLD_KEYS)}")
        base = {key: spec[key] for key in ("kind", "trajectories", "time_scales") if key in spec}
        hybrid = bool(spec.get("hybrid", False))
        each = spec.get("each")
        if each is None:
            split = SplitConfig(**base, data=data, set=set_name)
            out.append(Fold(fold_name(split), split, hybrid))
        else:
            if each not in EACH or base.get("trajectories") or base.get("time_scales"):
                raise QrInputError(where, f"each: {each!r} with named hold-outs",
                                   f"give each: time_scale or each: trajectory, and no names")
            values = list(dict.fromkeys(getattr(infos[f], each) for f in flights))
            for v in values:
                if v is None:
                    continue
                key = {"time_scale": "time_scales", "trajectory": "trajectories"}[each]
                split = SplitConfig(kind=base.get("kind", "trajectory"), **{key: [v]}, data=data, set=set_name)
                out.append(Fold(fold_name(split), split, hybrid, f"{split.kind}-each-{each}"))
    kept = []
    for f in out:
        try:
            assign(flights, f.split, infos)  # refuses a fold that leaves nothing to train on or to score
            kept.append(f)
        except QrInputError as e:
            if skipped is None:
                raise
            skipped.append((f.name, e.problem if hasattr(e, "problem") else str(e)))
    out = kept
    names = [f.name for f in out]
    if len(set(names)) < len(names):
        raise QrInputError(f"generalization.sets.{set_name}", "two folds hold out the same flights",
                           "list each split once")
    return out
