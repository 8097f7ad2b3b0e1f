"""A flight set's replays in the workflow (workflow/rules/replay.smk): which flights are replayed (those the
rollout holds out, :mod:`qr.holdout`'s repeat split, with a trajectory in the data set's file and a time scale)
and ``qr replay``'s overrides for them (the trajectory, the time scales, the controller's parameters)."""

from __future__ import annotations


def flight_trajectory(set_cfg: dict, flight: str) -> tuple[str, float | None] | None:
    """(trajectory name, time scale) a flight flew, from the set's ``flown:`` groups (:mod:`qr.flightsets`, the
    one record of what each flight flies; the time scale None where the source gives none), or None where the
    set does not describe the flight."""
    from ..flightsets import parse_flown

    if not set_cfg.get("flown"):
        return None
    info = parse_flown(set_cfg["flown"], list(set_cfg.get("flights") or [])).get(flight)
    return None if info is None else (info.trajectory, info.time_scale)


def _replayable(tr, trajectory_files: dict) -> bool:
    """A flight can be replayed: its trajectory has a file and its time scale is known."""
    return tr is not None and tr[0] in (trajectory_files or {}) and tr[1] is not None


def replayed_flights(set_cfg: dict, trajectory_files: dict) -> list[str]:
    """The flights the workflow replays: held out by the rollout's rule (the repeat split: the models the
    workflow writes for the set are trained on the others), with a trajectory file and a time scale."""
    from ..holdout import held_out_by_flight

    _, held_out = held_out_by_flight([str(f) for f in set_cfg["flights"]])
    return [f for f in held_out if _replayable(flight_trajectory(set_cfg, f), trajectory_files)]


def overrides_of(set_cfg: dict, flights: list[str], trajectory_files: dict) -> list[str]:
    """qr replay's overrides for a set's flights: the trajectory, a time scale per flight, the controller's
    documented parameters."""
    trs = [flight_trajectory(set_cfg, f) for f in flights]
    bad = [f for f, t in zip(flights, trs) if not _replayable(t, trajectory_files)]
    if bad:
        raise ValueError(f"flight {bad[0]}: no trajectory file or no time scale in the set's flown: groups")
    names = {t[0] for t in trs}
    if len(names) != 1:
        raise ValueError(f"the replayed flights fly {sorted(names)}: one trajectory per replay")
    ctrl = set_cfg.get("controller") or {}
    out = [f"replay.trajectory={trajectory_files[names.pop()]}",
           f"replay.timescale=[{','.join(repr(t[1]) for t in trs)}]"]
    if ctrl.get("mass") is not None:
        out.append(f"controller.mass={ctrl['mass']}")
    for k, v in ((ctrl.get("firmware") or {}).get("pwm") or {}).items():
        out.append(f"replay.firmware.pwm.{k}={v!r}")
    return out
