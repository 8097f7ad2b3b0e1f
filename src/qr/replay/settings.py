"""The replay's settings (the config group ``replay``, ``conf/replay/default.yaml``), each checked."""

from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from ..allowed import allowed
from ..errors import QrInputError
from .mixer import CrazyflieMixer, PwmModel

MIXERS = ("auto", "crazyflie", "ideal")
MOTOR_MAPS = ("auto", "fit", "firmware")
SOURCE = "conf/replay/default.yaml"


@functools.lru_cache(maxsize=1)
def _defaults() -> dict:
    """The defaults: ``conf/replay/default.yaml`` (their one place)."""
    import yaml

    from ..shipped import CONF_DIR

    return yaml.safe_load((Path(CONF_DIR) / "replay" / "default.yaml").read_text())


@dataclass(frozen=True)
class ReplaySettings:
    """``conf/replay/default.yaml`` says what each is; :meth:`from_dict` fills what is not given from there."""

    trajectory: str | None
    timescale: float | tuple  # one for all flights, or one per flight in the order given
    offset_s: float | None
    origin: tuple | None
    yaw0: float
    hold_s: float
    settle_s: float
    sim_rate_hz: float
    mixer: str
    motor_map: str
    firmware: CrazyflieMixer  # the Crazyflie firmware's power distribution (the crazyflie mixer), checked
    part_position_m: float
    part_attitude_deg: float
    max_error_m: float

    @classmethod
    def from_dict(cls, d: dict) -> ReplaySettings:
        d = dict(d)
        known = set(cls.__dataclass_fields__)
        bad = sorted(set(d) - known)
        if bad:
            raise QrInputError(f"replay.{bad[0]}", "is not a replay setting", f"use one of {', '.join(sorted(known))} "
                               f"({SOURCE})")
        base = _defaults()
        d = {**base, **d}
        out = {}
        rules = {"yaw0": allowed(), "hold_s": allowed(ge=0, le=3600), "settle_s": allowed(ge=0, le=60),
                 "sim_rate_hz": allowed(ge=100, le=100000), "part_position_m": allowed(gt=0),
                 "part_attitude_deg": allowed(gt=0, le=180), "max_error_m": allowed(gt=0)}
        for k, v in d.items():
            if k in rules:
                out[k] = float(rules[k].check(f"replay.{k}", v, base[k], SOURCE))
            elif k == "timescale":
                rule = allowed(gt=0, le=100)
                out[k] = (tuple(float(rule.check("replay.timescale", x, 1.0, SOURCE)) for x in v)
                          if isinstance(v, (list, tuple)) else float(rule.check("replay.timescale", v, 1.0, SOURCE)))
            elif k == "offset_s":
                out[k] = None if v is None else float(allowed().check("replay.offset_s", v, None, SOURCE))
            elif k == "origin":
                out[k] = None if v is None else _vector3("replay.origin", v)
            elif k in ("mixer", "motor_map"):
                names = MIXERS if k == "mixer" else MOTOR_MAPS
                if v not in names:
                    raise QrInputError(f"replay.{k}", f"{v!r} is not one of {', '.join(names)}",
                                       f"e.g. replay.{k}={base[k]} ({SOURCE})")
                out[k] = v
            elif k == "trajectory":
                out[k] = None if v in (None, "") else str(v)
            elif k == "firmware":
                out[k] = v
        return cls(**{**out, "firmware": _crazyflie_mixer(out["firmware"])})  # checked now, not minutes later

    def for_flight(self, i: int, n: int) -> ReplaySettings:
        """The settings of the ``i``-th of ``n`` flights (a time scale per flight picked)."""
        if not isinstance(self.timescale, tuple):
            return self
        if len(self.timescale) != n:
            raise QrInputError("replay.timescale", f"{len(self.timescale)} time scales for {n} flights",
                               "give one time scale, or one per flight in the order of the flights")
        return replace(self, timescale=self.timescale[i])

    def to_dict(self) -> dict:
        d = asdict(self)
        d["origin"] = list(self.origin) if self.origin is not None else None
        d["timescale"] = list(self.timescale) if isinstance(self.timescale, tuple) else self.timescale
        return d


def _crazyflie_mixer(f) -> CrazyflieMixer:
    """``replay.firmware`` (arm_length, thrust_to_torque, pwm: {d00, ...}) as the mixer, checked."""
    try:
        pwm = PwmModel(**{k: float(v) for k, v in f["pwm"].items()})
        mixer = CrazyflieMixer(float(f["arm_length"]), float(f["thrust_to_torque"]), pwm)
    except (KeyError, TypeError, ValueError) as e:
        raise QrInputError("replay.firmware", f"the firmware's power distribution is incomplete or not numeric "
                           f"({e})", f"give arm_length, thrust_to_torque and pwm: {{d00, d10, d01, d20, d11}} "
                           f"({SOURCE})") from None
    if not (mixer.arm_length > 0 and mixer.thrust_to_torque > 0 and pwm.d10 > 0):
        raise QrInputError("replay.firmware", "arm_length, thrust_to_torque and pwm.d10 must be positive",
                           f"see {SOURCE}")
    return mixer


def _vector3(key: str, v) -> tuple:
    try:
        out = tuple(float(x) for x in v)
    except (TypeError, ValueError):
        out = ()
    if len(out) != 3 or not all(math.isfinite(x) for x in out):
        raise QrInputError(key, f"{v!r} is not three numbers", f"e.g. {key}=[0,0,0.5] (m), or null to find it")
    return out


def compose_replay(controller: str, overrides=()) -> tuple[dict, ReplaySettings, set[str]]:
    """The config tree for ``qr replay`` (``controller=<name>`` selected where ``conf/controller/<name>.yaml``
    exists), its replay settings checked, and the controller keys the overrides set."""
    from ..config import _type_error, compose, to_dict
    from ..shipped import CONF_DIR

    overrides = list(overrides)
    chosen = [f"controller={controller}"] if (Path(CONF_DIR) / "controller" / f"{controller}.yaml").exists() else []
    try:
        cfg = to_dict(compose(chosen + overrides))
    except Exception as e:  # Hydra's errors are long; the first line says what is wrong
        mine = _type_error(e, overrides)
        if mine is not None:
            raise mine from None
        raise QrInputError("overrides", str(e).strip().splitlines()[0],
                           "use KEY=VALUE for keys in conf/ (e.g. replay.timescale=0.8, controller.mass=0.037)") from None
    given = {o.split("=", 1)[0].lstrip("+~").split(".", 1)[1] for o in overrides
             if "=" in o and o.lstrip("+~").startswith("controller.")}
    return cfg, ReplaySettings.from_dict(cfg["replay"]), given
