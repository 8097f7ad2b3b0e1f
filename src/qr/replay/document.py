"""``replay.json`` (schema ``qr.replay/1``, docs/spec/replay.md) of a :class:`qr.replay.replay.Replay`: the one
writer of that document."""

from __future__ import annotations

from .. import __version__

SCHEMA = "qr.replay/1"


def setpoints_block(f) -> dict:
    s, a = f.setup, f.setup.alignment
    mm = s.actuation.motor_map
    return {
        "trajectory": s.trajectory, "timescale": s.setpoints.timescale, "offset_s": a.offset_s,
        "offset_uncertainty_s": a.offset_uncertainty_s, "offset_halves_s": list(a.halves_s) if a.halves_s else None,
        "origin_m": list(a.origin), "yaw0_rad": s.setpoints.yaw0, "controller_mass_kg": s.controller_mass,
        "controller_mass_source": s.mass_source, "source": a.source, "fit_rms": a.fit_rms, "fit_unit": a.fit_unit,
        "window_s": list(s.window), "mixer": s.mixer, "motor_map": mm.to_dict() if mm is not None else None,
        "vbat_V": s.actuation.vbat if s.mixer == "crazyflie" else None, "sim_rate_hz": s.sim_rate_hz,
    }


def document(replay, config: dict | None = None) -> dict:
    labels = dict(zip(replay.vehicles, replay.labels))
    mixer = next((f.setup.actuation.mixer.to_dict() for f in replay.flights if f.setup.actuation.mixer is not None),
                 {"kind": "ideal"})
    kind = {f.setup.thrust_kind for f in replay.flights}
    thrust_kind = kind.pop() if len(kind) == 1 else "mixed"
    return {
        "schema": SCHEMA,
        "qr_version": __version__,
        "flights": [f.path for f in replay.flights],
        "vehicles": list(replay.vehicles),
        "labels": labels,
        "controller": replay.controller.to_dict(),
        "mixer": mixer,
        "config": config or {"replay": replay.settings.to_dict()},
        "setpoints": {f.path: setpoints_block(f) for f in replay.flights},
        "per_flight": {f.path: {"duration_s": float(f.setup.window[1] - f.setup.window[0]),
                                "models": {m.vehicle: m.errors.summary(replay.rotor_unit, f.setup.thrust_kind)
                                           for m in f.models}}
                       for f in replay.flights},
        "models": {v: e.summary(replay.rotor_unit, thrust_kind) for v, e in zip(replay.vehicles, replay.pooled)},
        "unknown": list(replay.unknown),
    }
