"""The controllers ``qr replay --controller NAME`` flies: ``lee`` (:mod:`.lee`), ``rotorpy_se3``
(:mod:`.rotorpy_controller`) or ``MODULE:CLASS`` (a user's :class:`qr.replay.controller.Controller`)."""

from __future__ import annotations

import importlib

from ..errors import QrInputError
from .controller import Controller


def controller_named(name: str, settings: dict | None = None) -> Controller:
    """The controller ``--controller`` names: ``lee`` (gains ``settings``: the ``controller`` config group),
    ``rotorpy_se3``, or ``MODULE:CLASS``."""
    if name == "lee":
        from .lee import LeeController, LeeGains

        return LeeController(LeeGains.from_dict(settings or {}))
    if name == "rotorpy_se3":
        from .rotorpy_controller import RotorPySE3

        return RotorPySE3()
    if ":" in name:
        module, cls = name.split(":", 1)
        try:
            obj = getattr(importlib.import_module(module), cls)
        except (ImportError, AttributeError) as e:
            raise QrInputError(name, f"controller class cannot be imported ({e})",
                               "give --controller MODULE:CLASS of an importable class (on PYTHONPATH)") from None
        ctrl = obj()
        if not callable(ctrl) or not hasattr(ctrl, "reset"):
            raise QrInputError(name, "is not a controller (it needs reset(vehicle, mass) and __call__(t, state, "
                                     "setpoint) -> Command)", "subclass qr.replay.controller.Controller")
        return ctrl
    raise QrInputError(name, "unknown controller", "use --controller lee, rotorpy_se3 or MODULE:CLASS")


def controllers_for(name: str, settings: dict, given: set[str] = frozenset()):
    """``log -> Controller``: a fresh controller per flight.  A ``qr synth`` flight made under the Lee
    controller is replayed with the gains it was flown with (recorded in its ``truth.json``), the keys the
    user set (``given``: ``controller.KEY=...``) applied on top."""
    def make(log) -> Controller:
        recorded = ((log.synth or {}).get("setpoints") or {}).get("controller") if log is not None else None
        if name == "lee" and recorded and recorded.get("name") == "lee":
            gains = {**recorded.get("gains", {}), **{k: v for k, v in settings.items() if k in given}}
            return controller_named(name, gains)
        return controller_named(name, settings)
    return make
