"""The simulation study's settings (``simulate.*``) as objects: the closed loop's :class:`SimSettings`, the
force models of its specs, the disturbance sources (:class:`Source`: the nominal vehicle, the TRUE plant, the
identification flight).

Force-model specs (``plant.force``, ``estimates.*``, ``stability.models.*``)::

    {model: thesis_model8, u_scale: 1e4}                    # eq. 4.38 on [v_b, u]
    {model: linear, inputs: [v_b, u], W: [[...]], b: [...], u_scale: 1, per_mass: false}
    {model: effects, effects: ["linear_drag:kx=0.3", ...]}  # catalog terms
    {model: extended_vehicle, path: extended_vehicle.yaml}  # qr diagnose's output
    {model: learned, path: DIR}                             # qr.models.load (learning stage)
    {model: fit_linear, inputs: [v_b, u]}                   # least squares on an identification flight
    {model: fit_effects, effects: [linear_drag, wind_force]}
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..effects import parse_effect_spec, validate_effect_list
from ..errors import QrInputError
from ..vehicle import load_vehicle
from . import disturbance as dist
from .control import Gains
from .study import Limits, Plant, SimSettings, identification_data


def settings(sim: dict) -> SimSettings:
    for key, cls in (("gains", Gains), ("limits", Limits)):
        bad = sorted(set(sim.get(key) or {}) - set(cls.__dataclass_fields__))
        if bad:
            raise QrInputError(f"sim.{key}", f"unknown key(s) {bad}", f"use {sorted(cls.__dataclass_fields__)}")
    rate = float(sim.get("rate", 1000.0))
    if rate < 500:
        raise QrInputError("simulate.rate", f"{rate} Hz is below 500 Hz", "simulate at 500 Hz or more (RK4 + rotor lag)")
    controller = sim.get("controller", "lqr")
    if controller not in ("lqr", "lee"):
        raise QrInputError("simulate.controller", f"{controller!r} is not lqr or lee", "simulate.controller=lee")
    return SimSettings(rate=rate, log_rate=float(sim.get("log_rate", 100.0)), duration=sim.get("duration"),
                       gains=Gains(**(sim.get("gains") or {})), limits=Limits(**(sim.get("limits") or {})),
                       controller=controller)


def parse_effects(items, where, vehicle=None) -> list[dict]:
    """Catalog effects given as ``'name:p=v,...'`` specs or ``{name, parameters}`` (in range for ``vehicle``)."""
    out = []
    for e in items or []:
        out.append(parse_effect_spec(e, vehicle) if isinstance(e, str) else e)
    return validate_effect_list(out, where, vehicle)


@dataclass
class Source:
    """A disturbance source: the nominal vehicle, the TRUE plant, and how to identify it."""

    name: str
    vehicle: object
    plant: Plant
    estimates: dict = field(default_factory=dict)
    ident_cfg: dict = field(default_factory=dict)
    settings: SimSettings = field(default_factory=SimSettings)
    _ident: tuple | None = None

    def identification(self):
        if self._ident is None:
            c = self.ident_cfg
            self._ident = identification_data(self.plant, float(c.get("duration_s", 60.0)), int(c.get("seed", 0)),
                                              float(c.get("accel_noise_m_s2", 0.0)), self.settings)
        return self._ident


KINDS = ("thesis_model8", "linear", "effects", "extended_vehicle", "learned", "fit_linear", "fit_effects")


def check_spec(spec, where: str) -> None:
    """Fail before any flight on a spec that cannot be built."""
    kind = (spec or {}).get("model")
    if kind not in KINDS:
        raise QrInputError(where, f"unknown force model {kind!r}", f"use model: {' | '.join(KINDS)}")
    if kind in ("extended_vehicle", "learned"):
        _path(spec, where)


def build_force(spec: dict, vehicle, source: Source | None, where: str):
    """A force model from a spec (see the module docstring)."""
    spec = dict(spec or {})
    kind = spec.get("model")
    name = spec.get("name", where.rsplit(".", 1)[-1])
    if kind == "thesis_model8":
        return dist.thesis_model8(float(spec.get("u_scale", dist.MODEL8_U_SCALE)))
    if kind == "linear":
        scale = vehicle.mass if spec.get("per_mass") else 1.0
        W = scale * np.asarray(spec["W"], dtype=float)
        b = scale * np.asarray(spec.get("b", [0, 0, 0]), dtype=float)
        return dist.LinearForce(W, b, tuple(spec["inputs"]), name, float(spec.get("u_scale", 1.0)))
    if kind == "effects":
        return dist.CatalogForce(parse_effects(spec.get("effects"), where, vehicle), vehicle, name)
    if kind == "extended_vehicle":
        nominal, effects = dist.extended_vehicle(_path(spec, where))
        return dist.CatalogForce(effects, nominal, name)
    if kind == "learned":
        return dist.LearnedForce(_path(spec, where), name)
    if kind in ("fit_linear", "fit_effects"):
        if source is None:
            raise QrInputError(where, f"'{kind}' needs a plant to fly an identification flight in",
                               "name the tracking source to identify in with 'source:'")
        s, f_a = source.identification()
        if kind == "fit_linear":
            return dist.fit_linear(s, f_a, tuple(spec["inputs"]), name, float(spec.get("u_scale", 1.0)))
        return dist.fit_effects(s, f_a, list(spec["effects"]), source.vehicle, name)
    check_spec(spec, where)
    raise AssertionError(kind)  # pragma: no cover


def _path(spec, where):
    p = spec.get("path")
    if not p:
        raise QrInputError(where, "no path given", f"set {where}.path (or disable the source with enabled: false)")
    return p


def no_leak(model, where):
    if "a_b" in getattr(model, "inputs", ()):
        raise QrInputError(where, "the model takes a_b, from which its label f_a is computed (it leaks the target)",
                           "use it in simulate.stability.models, not as a tracking disturbance or estimate")


def build_source(name: str, cfg: dict, sim: dict) -> Source:
    where = f"simulate.sources.{name}"
    veh = load_vehicle(cfg.get("vehicle") or sim["vehicle"])
    effects = validate_effect_list(veh.effects, where) + parse_effects((cfg.get("plant") or {}).get("effects"), where,
                                                                       veh)
    nominal = veh.with_changes(effects=[]) if veh.effects else veh
    pc = cfg.get("plant") or {}
    src = Source(name, nominal, Plant(nominal, effects), dict(cfg.get("estimates") or {}),
                 dict(sim.get("identification") or {}), settings(sim))
    if pc.get("force"):
        src.plant.force = build_force(pc["force"], nominal, None, f"{where}.plant.force")
        no_leak(src.plant.force, f"{where}.plant.force")
    return src


def enabled(cfg: dict) -> bool:
    return bool((cfg or {}).get("enabled", True))
