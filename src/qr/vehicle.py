"""Vehicle files: load, validate, save.  The one home of the vehicle parameters.

The format is ``flight-log.md``'s ``NAME.yaml``; the optional keys this project adds (``ground_z``, ``hub_z``,
rotor limits, ``effects``, learned terms, ``extends``, rotor properties): docs/ingest.md "Vehicle files".
"""

from __future__ import annotations

import copy
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from . import residual, torque_remainder
from .allowed import is_number
from .atomic import plain, write_text
from .errors import QrInputError, warn
from .rotors import LAYOUTS, CommandMap, RotorMap
from .shipped import shipped_vehicles, vehicle_file

REQUIRED = ("name", "mass", "inertia", "thrust_coeff", "torque_coeff", "rotor_speed_unit", "layout")
SPEED_UNITS = ("rpm", "rad_s")
SPEED_IN_RPM = {"rpm": 1.0, "rad_s": 60.0 / (2 * math.pi)}  # one rotor-speed unit, in rpm
OPTIONAL_DEFAULTS = {"ground_z": 0.0, "hub_z": 0.0, "motor_time_constant": 0.03}
# rotor and airframe properties the catalog has no term for (docs/ingest.md "Vehicle files"); their values mean "none"
ROTOR_PROPERTIES = {"rotor_inertia": 0.0, "rotor_torque_gains": 1.0, "flapping_pitch_ratio": 1.0}
KNOWN = set(REQUIRED) | {"arm_length", "rotor_speed_min", "rotor_speed_max", "effects", "extends",
                         "description", "source", "torque_remainder", "residual", "rotor_input", "command_map"} \
    | set(OPTIONAL_DEFAULTS) | set(ROTOR_PROPERTIES)
ROTOR_INPUTS = ("speed", "command")


@dataclass
class Vehicle:
    name: str
    mass: float
    inertia: np.ndarray  # (3,) principal Jxx, Jyy, Jzz (kg m^2)
    rotors: RotorMap
    rotor_speed_unit: str
    raw: dict = field(repr=False)  # the validated mapping (for saving / extending)
    residual: object = field(default=None, repr=False)  # a learned wrench (qr.residual.Residual), read at load

    @property
    def J(self) -> np.ndarray:
        return np.diag(self.inertia)

    @property
    def thrust_coeff(self) -> float:
        return self.rotors.thrust_coeff

    @property
    def torque_coeff(self) -> float:
        return self.rotors.torque_coeff

    @property
    def ground_z(self) -> float:
        return float(self.raw.get("ground_z", OPTIONAL_DEFAULTS["ground_z"]))

    @property
    def hub_z(self) -> float:
        """Height of the rotor hubs above the CG (m, body z; 0: in the CG's plane)."""
        return float(self.raw.get("hub_z", OPTIONAL_DEFAULTS["hub_z"]))

    @property
    def motor_time_constant(self) -> float:
        return float(self.raw.get("motor_time_constant", OPTIONAL_DEFAULTS["motor_time_constant"]))

    @property
    def rotor_inertia(self) -> float:
        """Each rotor's moment of inertia about its spin axis (kg m²; 0: not modelled)."""
        return float(self.raw.get("rotor_inertia", 0.0))

    @property
    def rotor_torque_gains(self) -> np.ndarray:
        """Each rotor's yaw-torque coefficient over ``torque_coeff`` (ones: as the file)."""
        return np.broadcast_to(np.asarray(self.raw.get("rotor_torque_gains", 1.0), float), (self.rotors.n,)).copy()

    @property
    def flapping_pitch_ratio(self) -> float:
        """The blade-flapping coefficient about body y over the catalog's (about x); 1: the same."""
        return float(self.raw.get("flapping_pitch_ratio", 1.0))

    @property
    def rotor_input(self) -> str:
        """``speed`` (the log's u1..u4 are rotor speeds) or ``command`` (normalised motor commands)."""
        return str(self.raw.get("rotor_input", "speed"))

    @property
    def command_map(self) -> CommandMap | None:
        m = self.raw.get("command_map")
        if self.rotor_input != "command" or m is None:
            return None
        n = self.rotors.n
        return CommandMap(*(np.broadcast_to(np.asarray(m.get(key, 0.0), dtype=float), (n,)).copy()
                            for key in ("a", "b", "k")), None if m.get("v_ref") is None else float(m["v_ref"]))

    @property
    def hover_speed(self) -> float:
        """Rotor speed (vehicle unit) at which four equal rotors carry m g."""
        return math.sqrt(self.mass * 9.81 / (self.rotors.n * self.thrust_coeff))

    @property
    def rotor_speed_min(self) -> float:
        return float(self.raw.get("rotor_speed_min", 0.0))

    @property
    def rotor_speed_max(self) -> float:
        # Default: thrust-to-weight 2.5, a typical small multirotor.
        return float(self.raw.get("rotor_speed_max", self.hover_speed * math.sqrt(2.5)))

    @property
    def effects(self) -> list[dict]:
        return list(self.raw.get("effects") or [])

    def with_changes(self, **changes) -> "Vehicle":
        """The vehicle with ``changes``; the file's own keys were warned about when it was loaded."""
        raw = copy.deepcopy(self.raw)
        raw.update(changes)
        return vehicle_from_dict(raw, quiet=True)

    def to_dict(self) -> dict:
        return copy.deepcopy(self.raw)


def _number(path, raw, key, positive=True, minimum=None):
    val = raw[key]
    if not is_number(val):
        raise QrInputError(path, f"vehicle key '{key}' is {val!r}, not a number",
                           f"give '{key}' as a number in SI units (no quotes)")
    x = float(val)
    if not math.isfinite(x) or (positive and x <= 0):
        raise QrInputError(path, f"vehicle key '{key}' is {val!r}, not a positive number",
                           f"set '{key}' to its physical (positive) value")
    if minimum is not None and x < minimum:
        raise QrInputError(path, f"vehicle key '{key}' is {val!r}, below {minimum:g}",
                           f"set '{key}' to its physical value (at least {minimum:g})")
    return x


def _near(key: str, keys) -> str | None:
    """The known key ``key`` is most likely a misspelling of (difflib's closest), or None."""
    import difflib

    close = difflib.get_close_matches(str(key), sorted(map(str, keys)), n=1)
    return close[0] if close else None


def _layout_entry(path, i, r):
    if not isinstance(r, dict) or not {"x", "y", "yaw_sign"} <= set(r):
        raise QrInputError(path, f"layout rotor {i} is {r!r}",
                           "give each rotor as {x: m, y: m, yaw_sign: +1 or -1}")
    for k in ("x", "y", "yaw_sign"):
        if not is_number(r[k]) or not math.isfinite(r[k]):
            raise QrInputError(path, f"layout rotor {i} has {k}: {r[k]!r}, not a number",
                               "give each rotor as {x: m, y: m, yaw_sign: +1 or -1}, numbers without quotes")
    if float(r["yaw_sign"]) not in (-1.0, 1.0):
        raise QrInputError(path, f"layout rotor {i} has yaw_sign {r['yaw_sign']!r}", "yaw_sign is +1 or -1")


def vehicle_from_dict(raw: dict, path: str | Path | None = None, quiet: bool = False) -> Vehicle:
    """A validated vehicle; ``quiet``: no warnings (a vehicle derived from one already loaded)."""
    warn_ = (lambda *a: None) if quiet else warn
    _check_required(path, raw)
    raw = dict(raw)
    mass = _number(path, raw, "mass")
    ct = _number(path, raw, "thrust_coeff")
    cq = _number(path, raw, "torque_coeff")
    arm = _number(path, raw, "arm_length") if "arm_length" in raw else None
    J = _inertia(path, raw["inertia"], warn_)
    unit = raw["rotor_speed_unit"]
    if not isinstance(unit, str) or unit not in SPEED_UNITS:
        raise QrInputError(path, f"rotor_speed_unit is {unit!r}",
                           f"use one of {', '.join(SPEED_UNITS)}")
    layout = raw["layout"]
    rotors = _rotor_map(path, layout, arm, ct, cq)
    _check_optional_numbers(path, raw, rotors)
    _check_rotor_input(path, raw, warn_)
    _check_rotor_properties(path, raw, len(layout) if isinstance(layout, list) else 4)
    unknown = sorted(set(map(str, raw)) - KNOWN)
    if unknown:
        near = {k: c for k in unknown if (c := _near(k, KNOWN - set(raw)))}
        fix = "; ".join(f"'{k}' is probably '{c}'" for k, c in near.items())
        warn_(path, f"vehicle file has unknown key(s) {unknown} (ignored)",
              (fix + ": correct the spelling" if near else "remove them or check their spelling"))
    vehicle = Vehicle(str(raw["name"]), mass, J, rotors, unit, raw)
    if raw.get("effects") is not None:
        from .effects import validate_effect_list
        # all parameters given, numbers, and within what this vehicle can physically have
        raw["effects"] = validate_effect_list(raw["effects"], path, vehicle)
    if raw.get("torque_remainder") is not None:
        raw["torque_remainder"] = torque_remainder.validate(raw["torque_remainder"], path)
    if raw.get("residual") is not None:
        vehicle.residual = residual.load(raw["residual"], path)
    return vehicle


def _check_required(path, raw) -> None:
    """A mapping with every required key (``arm_length`` too for a named layout), else the keys it lacks."""
    if not isinstance(raw, dict):
        raise QrInputError(path, "vehicle file is not a YAML mapping",
                           "write 'key: value' lines as in docs/spec/flight-log.md")
    missing = [k for k in REQUIRED if k not in raw]
    if raw.get("layout") in LAYOUTS and "arm_length" not in raw:
        missing.append("arm_length")
    if missing:
        hints = [f"'{k}'" + (f" (found {c!r})" if (c := _near(k, raw)) else "") for k in missing]
        raise QrInputError(path, f"vehicle file lacks key(s) {', '.join(hints)}",
                           "add them as in docs/spec/flight-log.md")


def _inertia(path, inertia, warn_) -> np.ndarray:
    """The principal inertias: three positive numbers (a warning where they break the triangle inequality)."""
    if not (isinstance(inertia, (list, tuple)) and len(inertia) == 3):
        raise QrInputError(path, f"vehicle key 'inertia' is {inertia!r}, not three numbers",
                           "give the diagonal [Jxx, Jyy, Jzz] in kg m^2")
    if not all(is_number(x) for x in inertia):
        raise QrInputError(path, f"vehicle key 'inertia' is {inertia!r}, not three numbers",
                           "give the diagonal [Jxx, Jyy, Jzz] in kg m^2")
    J = np.array([float(x) for x in inertia])
    if not np.all(np.isfinite(J)) or np.any(J <= 0):
        raise QrInputError(path, f"vehicle inertia {[float(x) for x in J]} has a non-positive entry",
                           "give positive principal inertias in kg m^2")
    for i in range(3):
        a, b, c = J[i], J[(i + 1) % 3], J[(i + 2) % 3]
        if a > b + c:
            names = ["Jxx", "Jyy", "Jzz"]
            warn_(path, f"inertia {[float(x) for x in J]} breaks the triangle inequality "
                       f"({names[i]} > {names[(i + 1) % 3]} + {names[(i + 2) % 3]}): no rigid body has it",
                 "use measured principal inertias; for a symmetric quadrotor Jzz is at most Jxx + Jyy "
                 "(the thesis's Table 4.1 value is such an error)")
            break
    return J


def _rotor_map(path, layout, arm, ct, cq) -> RotorMap:
    """The rotor map of a named layout or of four rotors, checked to control thrust, roll, pitch and yaw."""
    if not (isinstance(layout, str) and layout in LAYOUTS):
        if not isinstance(layout, list) or len(layout) != 4:
            raise QrInputError(path, f"layout is {layout!r}: neither {' nor '.join(map(repr, LAYOUTS))} nor a "
                                     "list of four rotors", "write layout: x, layout: plus, or four entries "
                                                            "{x, y, yaw_sign} (docs/ingest.md, 'Vehicle files')")
        for i, r in enumerate(layout, 1):
            _layout_entry(path, i, r)
    rotors = RotorMap.from_layout(layout, arm, ct, cq)
    if not np.all(np.isfinite(rotors.matrix)):
        raise QrInputError(path, "thrust_coeff, torque_coeff and the rotor positions overflow the rotor map",
                           "give the coefficients and positions in SI units (N per unit^2, m)")
    if abs(np.linalg.det(rotors.matrix)) < 1e-300 or np.linalg.matrix_rank(rotors.matrix) < 4:
        raise QrInputError(path, "layout gives a rotor map that cannot control thrust, roll, pitch and yaw",
                           "check rotor positions and yaw signs (two of each sign, not collinear)")
    return rotors


def _check_optional_numbers(path, raw: dict, rotors: RotorMap) -> None:
    """The optional numeric keys: numbers in their ranges; ``hub_z`` within twice the largest rotor distance."""
    if "rotor_speed_max" in raw:
        _number(path, raw, "rotor_speed_max")
    for k in ("ground_z", "hub_z", "motor_time_constant", "rotor_speed_min"):
        if k in raw:
            _number(path, raw, k, positive=k == "motor_time_constant", minimum=0 if k == "rotor_speed_min" else None)
    if "hub_z" in raw:
        arm_max = float(np.max(np.hypot(*rotors.positions.T)))
        if abs(float(raw["hub_z"])) > 2 * arm_max:
            raise QrInputError(path, f"hub_z is {raw['hub_z']!r} m, more than twice the largest rotor distance "
                                     f"({arm_max:g} m) from the CG",
                               "give the hubs' height above the CG in metres (0 when they sit in the CG's plane)")


def _check_rotor_properties(path, raw: dict, n: int) -> None:
    """``rotor_inertia`` ≥ 0; ``rotor_torque_gains`` one positive number per rotor; ``flapping_pitch_ratio`` > 0."""
    if "rotor_inertia" in raw:
        _number(path, raw, "rotor_inertia", positive=False, minimum=0)
    if "flapping_pitch_ratio" in raw:
        _number(path, raw, "flapping_pitch_ratio")
    g = raw.get("rotor_torque_gains")
    if g is not None and not (isinstance(g, list) and len(g) == n
                              and all(is_number(x) and math.isfinite(x) and x > 0 for x in g)):
        raise QrInputError(path, f"rotor_torque_gains is {g!r}, not {n} positive numbers (one per rotor)",
                           f"write rotor_torque_gains: [{', '.join(['1.0'] * n)}] (each rotor's C_Q over torque_coeff)")


def _check_rotor_input(path, raw: dict, warn_=warn) -> None:
    """``rotor_input: command`` needs a ``command_map`` whose thrust rises with the command."""
    kind = raw.get("rotor_input", "speed")
    if kind not in ROTOR_INPUTS:
        raise QrInputError(path, f"rotor_input is {kind!r}", f"use one of {', '.join(ROTOR_INPUTS)}")
    m = raw.get("command_map")
    if kind == "speed":
        if m is not None:
            warn_(path, "command_map is given but rotor_input is speed (the map is ignored)",
                 "set rotor_input: command if the log's u1..u4 are motor commands")
        return
    fix = "write command_map: {a: N, b: N, k: N} (thrust = a + b c + k c², c in [0, 1]; lists of 4 per rotor)"
    if not isinstance(m, dict) or not {"b", "k"} <= set(m):
        raise QrInputError(path, "rotor_input is command but command_map (with b and k) is missing", fix)
    extra = sorted(set(m) - {"a", "b", "k", "v_ref"})
    if extra:
        raise QrInputError(path, f"command_map has unknown key(s) {extra}", fix + ", optional v_ref (V)")
    coef = {}
    for key in ("a", "b", "k"):
        v = m.get(key, 0.0)
        vals = v if isinstance(v, (list, tuple)) else [v]
        if len(vals) not in (1, 4) or not all(is_number(x) and math.isfinite(float(x)) for x in vals):
            raise QrInputError(path, f"command_map.{key} is {v!r}, not a number or four numbers", fix)
        coef[key] = np.array([float(x) for x in vals])
    b, k = np.broadcast_arrays(coef["b"], coef["k"])
    if np.any(b < 0) or np.any(b + 2 * k < 0) or np.any(coef["a"] + b + k <= 0):
        raise QrInputError(path, f"command_map gives a thrust that does not rise with the command (a={m.get('a', 0)}, "
                                 f"b={m['b']}, k={m['k']})", "check the signs: b >= 0, b + 2 k >= 0, a + b + k > 0")
    if m.get("v_ref") is not None and not (is_number(m["v_ref"]) and float(m["v_ref"]) > 0):
        raise QrInputError(path, f"command_map.v_ref is {m['v_ref']!r}", "give the reference battery voltage in V")


class _Loader(yaml.SafeLoader):
    """Safe YAML with YAML 1.2 floats: PyYAML reads ``thrust_coeff: 1e-8`` (no dot) as the string '1e-8'."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"))


def _read_yaml(path: Path, chain: tuple = ()) -> dict:
    """The file's mapping, with ``extends:`` resolved (``chain``: the files that extend this one)."""
    if not path.exists():
        raise QrInputError(path, "vehicle file does not exist",
                           f"check the path, or name a shipped vehicle ({', '.join(shipped_vehicles())})")
    if path.is_dir():
        raise QrInputError(path, "is a folder, not a vehicle file",
                           "give the vehicle's YAML file (e.g. conf/vehicle/NAME.yaml)")
    try:
        data = path.read_bytes()
    except OSError as e:
        raise QrInputError(path, f"vehicle file cannot be read ({e.strerror})", "check its permissions") from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = data[:e.start].count(b"\n") + 1
        raise QrInputError(path, f"vehicle file is not UTF-8 text (byte 0x{data[e.start]:02x} at line {line})",
                           "save it as UTF-8 (or keep it ASCII)") from None
    try:
        raw = yaml.load(text, Loader=_Loader)
    except yaml.YAMLError as e:
        line = getattr(getattr(e, "problem_mark", None), "line", None)
        where = f" at line {line + 1}" if line is not None else ""
        raise QrInputError(path, f"vehicle file is not valid YAML{where}",
                           "fix the syntax (key: value, lists in [ ] or '- ' lines)") from None
    except RecursionError:  # anchors nested thousands deep
        raise QrInputError(path, "vehicle file nests too deep", "write a flat 'key: value' file") from None
    if raw is None:
        raise QrInputError(path, "vehicle file is empty", "write the keys of docs/spec/flight-log.md")
    if isinstance(raw, dict) and "residual" in raw:  # its model file: relative to the file that names it
        raw["residual"] = residual.absolute(raw["residual"], path.parent)
    if isinstance(raw, dict) and "extends" in raw:
        base_name = raw["extends"]
        if not isinstance(base_name, str) or not base_name.strip():
            raise QrInputError(path, f"'extends: {base_name!r}' is not a file name",
                               "give the path of the vehicle this one builds on, relative to this file")
        base_path = (path.parent / base_name).resolve()
        here = [*chain, path.resolve()]
        if base_path in here:
            cycle = " -> ".join(p.name for p in here[here.index(base_path):] + [base_path])
            raise QrInputError(path, f"'extends: {base_name}' makes a cycle ({cycle})",
                               "a vehicle file cannot extend itself, directly or through others: remove one 'extends:'")
        if not base_path.exists():
            raise QrInputError(path, f"'extends: {base_name}' names {base_path}, which does not exist",
                               "give the path of the vehicle this one builds on, relative to this file")
        base = _read_yaml(base_path, tuple(here))
        if not isinstance(base, dict):
            raise QrInputError(base_path, "vehicle file is not a YAML mapping",
                               "write 'key: value' lines as in docs/spec/flight-log.md")
        base.update({k: v for k, v in raw.items() if k != "extends"})
        raw = base
    return raw


def load_vehicle(path: str | Path) -> Vehicle:
    """A vehicle file, or a shipped vehicle by name (``asctec_hummingbird``: ``conf/vehicle/<name>.yaml``,
    found in an installed qr too)."""
    path = vehicle_file(path)
    return vehicle_from_dict(_read_yaml(path), path)


def save_vehicle(vehicle: Vehicle | dict, path: str | Path, header: str | None = None) -> None:
    raw = vehicle.to_dict() if isinstance(vehicle, Vehicle) else dict(vehicle)
    raw.pop("extends", None)
    if "residual" in raw:  # its model file, as seen from where this file goes
        raw["residual"] = residual.relative(raw["residual"], Path(path).parent)
    text = yaml.safe_dump(plain(raw), sort_keys=False, default_flow_style=None)
    if header:
        text = "".join(f"# {line}\n" for line in header.splitlines()) + text
    write_text(path, text)


