"""`mapping.md` leaves nothing of a vehicle file out, and each row's number is its stated formula.

Every kind of vehicle file qr writes or ships (the nominal files of conf/vehicle, one in rad/s with a named
layout, an extended model with every catalog effect, a refined one, a hybrid with a learned wrench and a
learned torque remainder), exported to each simulator:

- every key of the loaded file and every effect it names is a row (docs/spec/export.md: "for every
  parameter and named effect of the vehicle"), and the counts line counts the rows;
- every row that states a formula: the formula, evaluated by this test's own reading of it on the vehicle
  file's own numbers (symbols computed here from the YAML, not by qr), gives the numbers of the row's value
  column (to 1e-9, the files' 10 digits), and each of them is a number of the simulator's files (a row whose
  key names something in them); a row that states a number of the vehicle without a formula fails.
"""

import math
import re

import numpy as np
import pytest

from conftest import ROOT, VEHICLES
import simulators as S
from qr.effects import CATALOG
from qr.stages.export import run_export
from qr.vehicle import load_vehicle, save_vehicle

EXTENDED = ROOT / "tests" / "export" / "crazyflie21_brushless_extended.yaml"
TARGETS = ("rotorpy", "mujoco", "px4-gz")
# effect parameters for the formulas' check: every one non-zero and distinct (a swapped symbol shows), of sizes
# the Crazyflie files accept; an effect not listed (a new catalog entry) gets the catalog's neutral values
EXAMPLE = {
    "linear_drag": {"kx": 0.011, "ky": 0.013, "kz": 0.0097}, "quadratic_drag": {"cx": 0.009, "cy": 0.014, "cz": 0.021},
    "rotor_drag": {"k": 1.7e-7}, "wind_force": {"fx": -0.0011, "fy": 0.0052, "fz": -0.0043},
    "body_force_bias": {"bx": -0.0031, "by": -0.0047, "bz": -0.0083}, "thrust_gain": {"gain": 1.031},
    "mass_error": {"dm": 0.0019}, "ground_effect": {"k": 0.00035},
    "motor_imbalance": {"d1": 0.027, "d2": -0.018, "d3": 0.006, "d4": 0.011},
    "cg_offset": {"rx": -0.00041, "ry": 0.00012}, "torque_bias": {"tx": 1.3e-5, "ty": -2.2e-5, "tz": 1.1e-6},
    "yaw_torque_gain": {"gain": 0.23}, "inertia_error": {"dJxx": 5.9e-6, "dJyy": 1.2e-6, "dJzz": -2.1e-6},
    "marker_offset": {"rx": 0.0027, "ry": -0.0013, "rz": 0.017}, "blade_flapping": {"k": 6.1e-4},
    "actuator_delay": {"delay_s": 0.012}, "rotor_drag_moment": {"k": 2.3e-7}, "translational_lift": {"k": 4.1e-4},
}
# the rad/s file carries a key qr does not know, on purpose (its row is checked): its warning is expected
pytestmark = pytest.mark.filterwarnings(r"ignore:.*unknown key\(s\) \['battery_cells'\]")
NUMBER = re.compile(r"(?<![\w.])[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?(?![\w.])")


def every_effect():
    out = []
    for name, eff in CATALOG.items():
        params = EXAMPLE.get(name) or dict(zip(eff.params, eff.neutral))
        out.append({"name": name, "parameters": dict(params)})
    return out


@pytest.fixture(scope="module")
def vehicle_files(tmp_path_factory):
    """name -> path of each kind of vehicle file."""
    tmp = tmp_path_factory.mktemp("vehicles")
    files = {p.stem: p for p in sorted(VEHICLES.glob("*.yaml"))}  # the nominal ones, as shipped
    hb = load_vehicle(VEHICLES / "asctec_hummingbird.yaml").to_dict()
    f = 2 * math.pi / 60
    hb.update(rotor_speed_unit="rad_s", thrust_coeff=hb["thrust_coeff"] / f**2, torque_coeff=hb["torque_coeff"] / f**2,
              rotor_speed_min=hb["rotor_speed_min"] * f, rotor_speed_max=hb["rotor_speed_max"] * f, ground_z=-0.05,
              description="the Hummingbird in rad/s", source="tests", battery_cells=3)  # a key qr does not know
    save_vehicle(hb, tmp / "hummingbird_rad_s.yaml")
    files["hummingbird_rad_s"] = tmp / "hummingbird_rad_s.yaml"
    brushless = load_vehicle(VEHICLES / "crazyflie21_brushless.yaml")
    save_vehicle(brushless.with_changes(effects=every_effect(), ground_z=0.02, hub_z=0.011), tmp / "every_effect.yaml")
    files["every_effect"] = tmp / "every_effect.yaml"
    # refined: what diagnose.refine=rollout writes, the named effects then the vehicle's coefficients refined
    refined = load_vehicle(EXTENDED).effects + [{"name": n, "parameters": EXAMPLE[n]}
                                               for n in ("thrust_gain", "actuator_delay")]
    save_vehicle(brushless.with_changes(effects=refined), tmp / "refined.yaml")
    files["refined"] = tmp / "refined.yaml"
    hybrid = load_vehicle(tmp / "every_effect.yaml").with_changes(description="a hybrid", source="tests")
    files["hybrid"] = S.hybrid_file(hybrid, tmp / "hybrid", remainder=2e-6)
    files["hybrid_of_extended"] = S.hybrid_file(load_vehicle(EXTENDED), tmp / "hybrid2")
    return files


@pytest.fixture(scope="module")
def exports(vehicle_files, tmp_path_factory):
    """(vehicle name, target) -> the export folder."""
    tmp = tmp_path_factory.mktemp("exports")
    out = {}
    for name, path in vehicle_files.items():
        for to in TARGETS:
            out[name, to] = tmp / f"{name}-{to}"
            run_export(path, to, out[name, to])
    return out


def table(folder):
    """mapping.md's rows as dicts (columns by the header's names)."""
    text = (folder / "mapping.md").read_text()
    lines = [line for line in text.splitlines() if line.startswith("| ")]
    head = [c.strip() for c in lines[0].strip("|").split(" | ")]
    assert head == ["qr item", "qr value", "simulator key", "simulator value", "formula", "mapping",
                    "conversion, condition or size"]
    return text, [dict(zip(head, (c.strip() for c in line.strip().strip("|").split(" | ")))) for line in lines[1:]]


def tokens(cell: str) -> set[str]:
    return set(re.split(r"[^\w]+", cell))


def test_every_key_and_effect_of_every_vehicle_file_is_a_row(vehicle_files, exports):
    for (name, to), folder in exports.items():
        vehicle = load_vehicle(vehicle_files[name])
        text, rows = table(folder)
        items = [tokens(r["qr item"]) for r in rows]
        expected = [k for k in vehicle.raw if k != "effects"] + [e["name"] for e in vehicle.effects]
        missing = [k for k in expected if not any(k in t for t in items)]
        assert not missing, (name, to, missing)
        statuses = [r["mapping"] for r in rows]
        assert set(statuses) <= {"exact", "approximate", "impossible"}
        counts = {s: statuses.count(s) for s in ("exact", "approximate", "impossible")}
        assert (f"{len(rows)} items: {counts['exact']} exact, {counts['approximate']} approximate, "
                f"{counts['impossible']} impossible") in text
    # the every-effect file indeed names the whole catalog, the hybrids both learned terms
    assert {e["name"] for e in load_vehicle(vehicle_files["every_effect"]).effects} == set(CATALOG)
    assert {"residual", "torque_remainder"} <= set(load_vehicle(vehicle_files["hybrid"]).raw)
    row = next(r for r in table(exports["hummingbird_rad_s", "px4-gz"])[1] if r["qr item"] == "battery_cells")
    assert row["mapping"] == "impossible" and "qr ignores it" in row["conversion, condition or size"]


def test_a_learned_wrench_is_flown_or_listed_impossible_with_its_size(vehicle_files, exports):
    """RotorPy and MuJoCo fly the network (exact, with the module that evaluates it); PX4-gz lists it as
    impossible with its RMS force and torque over the training flights, as the vehicle file recorded them."""
    rec = load_vehicle(vehicle_files["hybrid"]).raw["residual"]["size"]
    weight = 0.037 * 9.81 + EXAMPLE["mass_error"]["dm"] * 9.81
    for to, status in (("rotorpy", "exact"), ("mujoco", "exact"), ("px4-gz", "impossible")):
        _, rows = table(exports["hybrid", to])
        row = next(r for r in rows if r["qr item"] == "residual")
        assert row["mapping"] == status, (to, row)
        note = row["conversion, condition or size"]
        assert f"force {rec['rms_force']:.3g} N ({100 * rec['rms_force'] / weight:.3g} % of the weight)" in note, note
        assert f"torque {rec['rms_torque']:.3g} N m" in note and "hover.csv" in note
        assert "MLP [17, 12, 6] (tanh) from v_b, omega, g_b, u, u2" in row["qr value"]
    # a file without the record says so instead of a number
    raw = load_vehicle(vehicle_files["hybrid_of_extended"]).to_dict()
    raw["residual"].pop("size")
    path = vehicle_files["hybrid_of_extended"].parent / "no_size.yaml"
    save_vehicle(raw, path)
    out = path.parent / "no_size_px4"
    run_export(path, "px4-gz", out)
    row = next(r for r in table(out)[1] if r["qr item"] == "residual")
    assert "not recorded in this file" in row["conversion, condition or size"] and row["mapping"] == "impossible"


# ---- the formulas, read by this test ---------------------------------------------------------------------

def symbols(path) -> dict:
    """The formulas' symbols (docs/export.md, "Formulas") from the vehicle file's own numbers."""
    v = load_vehicle(path)
    raw = v.raw
    f = 2 * math.pi / 60 if raw["rotor_speed_unit"] == "rpm" else 1.0
    sym = {"f": f, "g": 9.81, "n": 4, "m": float(raw["mass"]), "C_T": float(raw["thrust_coeff"]),
           "C_Q": float(raw["torque_coeff"]), "τ_m": v.motor_time_constant, "u_min": v.rotor_speed_min,
           "u_max": v.rotor_speed_max, "ground_z": v.ground_z,
           "hub_z": float(raw.get("hub_z", 0.0))}
    sym.update({f"J_{a}": float(j) for a, j in zip(("xx", "yy", "zz"), raw["inertia"])})
    for i, ((x, y), s) in enumerate(zip(v.rotors.positions, v.rotors.yaw_signs), 1):
        sym[f"x_{i}"], sym[f"y_{i}"], sym[f"s_{i}"], sym[f"d_{i}"] = float(x), float(y), float(s), 0.0
    for e in v.effects:
        for k, val in e["parameters"].items():
            key = f"{e['name']}__{k}"
            sym[key] = sym.get(key, 1.0) * val if k == "gain" else sym.get(key, 0.0) + val
        if e["name"] == "motor_imbalance":
            for i in range(1, 5):
                sym[f"d_{i}"] = sym[f"motor_imbalance__d{i}"]
    gain = sym.get("thrust_gain__gain", 1.0)
    k = [sym["C_T"] * gain * (1 + sym[f"d_{i}"]) / f**2 for i in range(1, 5)]
    sym["ω_h"] = math.sqrt((sym["m"] + sym.get("mass_error__dm", 0.0)) * 9.81 / sum(k))
    return sym


def evaluate(formula: str, sym: dict) -> list[float]:
    """The numbers a formula states: ``·`` ``×`` multiply, ``−`` subtracts, ``²`` squares, ``√`` roots,
    ``effect.param`` is a parameter, ``_i`` repeats the formula for rotors 1..n, commas separate values (one
    value for a row of n: every rotor's)."""
    py = (formula.replace("·", "*").replace("×", "*").replace("−", "-").replace("²", "**2").replace("√", "sqrt"))
    py = re.sub(r"\b([A-Za-z_]\w*)\.([A-Za-z_]\w*)", r"\1__\2", py)
    env = {"__builtins__": {}, "sqrt": math.sqrt, "round": round, **sym}
    exprs = [re.sub(r"_i\b", f"_{i}", py) for i in range(1, sym["n"] + 1)] if re.search(r"_i\b", py) else [py]
    return [float(x) for e in exprs for x in np.ravel(np.asarray(eval(e, env), dtype=float))]  # noqa: S307


def file_numbers(folder) -> np.ndarray:
    """Every number in the simulator's files (mapping.md aside)."""
    out = []
    for p in folder.rglob("*"):
        if p.is_file() and p.suffix in (".py", ".xml", ".sdf", ".params", ".config"):
            out += [float(x) for x in NUMBER.findall(p.read_text())]
    return np.array(out)


def close(a, b) -> bool:
    return abs(a - b) <= 1e-9 * max(abs(a), abs(b)) + 1e-15


def test_each_rows_number_is_its_formula_of_the_vehicle_files_numbers(vehicle_files, exports):
    checked = {to: 0 for to in TARGETS}
    for (name, to), folder in exports.items():
        sym = symbols(vehicle_files[name])
        numbers = file_numbers(folder)
        for r in table(folder)[1]:
            stated = [float(x) for x in NUMBER.findall(r["simulator value"])]
            if r["formula"] == "-":
                # a number of the vehicle's with no formula would be unchecked
                assert not stated or r["qr value"] == "-", (name, to, r)
                continue
            values = evaluate(r["formula"], sym)
            if len(values) == 1 and len(stated) == sym["n"]:  # one formula for every rotor's value
                values = values * sym["n"]
            assert len(values) == len(stated) and all(map(close, values, stated)), (name, to, r, values)
            if r["simulator key"] != "-":  # the number is in the files, where the key says
                for x in values:
                    assert np.any(np.abs(numbers - x) <= 1e-9 * np.maximum(abs(x), np.abs(numbers)) + 1e-15), \
                        (name, to, r["qr item"], x)
            checked[to] += 1
    assert all(n > 50 for n in checked.values()), checked


def test_the_px4_rows_say_what_they_hold(tmp_path):
    """The thrust row's note is the thrust's conversion (not the inertia's), and momentConstant's formula is the
    C_Q / C_T that is written (0.006 m for the Crazyflie's C_T, C_Q), not C_Q / f²."""
    run_export(VEHICLES / "crazyflie21_brushless.yaml", "px4-gz", tmp_path / "gz")
    rows = {r["qr item"]: r for r in table(tmp_path / "gz")[1]}
    assert rows["thrust_coeff"]["formula"] == "C_T / f²" and "inertia" not in rows["thrust_coeff"][
        "conversion, condition or size"]
    assert "inertia" in rows["inertia"]["conversion, condition or size"]
    assert "mass" in rows["mass"]["conversion, condition or size"]
    moment = rows["torque_coeff"]
    assert moment["simulator key"] == "momentConstant" and moment["formula"] == "C_Q / C_T"
    assert [float(x) for x in NUMBER.findall(moment["simulator value"])] == pytest.approx([0.006] * 4, rel=1e-6)
    assert "f²" not in moment["formula"] and "C_Q / C_T" in moment["conversion, condition or size"]
