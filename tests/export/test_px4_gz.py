"""The PX4 / Gazebo Sim export: the SDF parses, its names and units are the stock x500's, every number is
the hand-derived conversion of the vehicle's.

Reference: PX4-gazebo-models, models/x500/model.sdf and models/x500_base/model.sdf (the stock PX4 x500):
its MulticopterMotorModel plugins carry the elements below in this order, its links are ``base_link``
and ``rotor_0..3`` on ``rotor_<i>_joint`` (revolute about z), its motorConstant 8.54858e-06 N/(rad/s)²
carries the 2 kg x500 at 759 rad/s, under its maxRotVelocity 1000 rad/s, and its momentConstant 0.016
is a length (m: torque per thrust).
"""

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from conftest import VEHICLES
from qr.stages.export import run_export
from qr.vehicle import load_vehicle, save_vehicle

X500_PLUGIN_ELEMENTS = ["jointName", "linkName", "turningDirection", "timeConstantUp", "timeConstantDown",
                        "maxRotVelocity", "motorConstant", "momentConstant", "commandSubTopic", "motorNumber",
                        "rotorDragCoefficient", "rollingMomentCoefficient", "rotorVelocitySlowdownSim", "motorType"]
X500_PLUGIN = ("gz-sim-multicopter-motor-model-system", "gz::sim::systems::MulticopterMotorModel")
F = 2 * math.pi / 60  # rad/s per rpm
CT, CQ = 4.228755e-10, 2.537253e-12  # conf/vehicle/crazyflie21_brushless.yaml, N/rpm², N m/rpm²
A = 0.0325269  # its rotors at (±A, ±A)


def export(vehicle_path, out):
    run_export(vehicle_path, "px4-gz", out)
    root = ET.parse(out / "crazyflie21_brushless" / "model.sdf").getroot()
    params = {}
    for line in (out / "crazyflie21_brushless.params").read_text().splitlines():
        if not line.startswith("#"):
            _, _, name, value, typ = line.split("\t")
            params[name] = (float(value), int(typ))
    return root, params


def plugins(root):
    return [p for p in root.iter("plugin") if p.get("name") == X500_PLUGIN[1]]


def test_the_sdf_has_the_x500_names_and_the_hand_derived_numbers(tmp_path):
    root, params = export(VEHICLES / "crazyflie21_brushless.yaml", tmp_path)
    assert root.tag == "sdf" and root.get("version") == "1.9"
    model = root.find("model")
    assert [link.get("name") for link in model.findall("link")] == ["base_link", "rotor_0", "rotor_1", "rotor_2",
                                                                      "rotor_3"]
    for j in model.findall("joint"):
        assert j.get("type") == "revolute" and j.find("axis/xyz").text == "0 0 1"
    ps = plugins(root)
    assert len(ps) == 4 and all(p.get("filename") == X500_PLUGIN[0] for p in ps)
    for i, p in enumerate(ps):
        assert [c.tag for c in p] == X500_PLUGIN_ELEMENTS
        v = {c.tag: c.text for c in p}
        assert v["jointName"] == f"rotor_{i}_joint" and v["linkName"] == f"rotor_{i}" and v["motorNumber"] == str(i)
        # yaw signs -1, +1, -1, +1: the reaction torque opposes the spin, so ccw, cw, ccw, cw
        assert v["turningDirection"] == ("ccw" if i % 2 == 0 else "cw")
        assert float(v["motorConstant"]) == pytest.approx(CT / F**2, rel=1e-9)  # 3.8562e-08 N/(rad/s)²
        assert float(v["momentConstant"]) == pytest.approx(0.006, rel=1e-6)  # C_Q / C_T, m
        assert float(v["maxRotVelocity"]) == pytest.approx(30000 * F, rel=1e-9)  # 3141.59 rad/s
        assert float(v["timeConstantUp"]) == float(v["timeConstantDown"]) == 0.02
        assert float(v["rotorDragCoefficient"]) == 0 and float(v["rollingMomentCoefficient"]) == 0
        assert v["motorType"] == "velocity" and v["commandSubTopic"] == "command/motor_speed"
        # the units are the x500's: rad/s and N/(rad/s)² carry the vehicle below maxRotVelocity, as there
        hover = math.sqrt(0.037 * 9.81 / (4 * float(v["motorConstant"])))
        assert 0.3 * float(v["maxRotVelocity"]) < hover < float(v["maxRotVelocity"])
    # PX4, FRD relative to the CG: rotor 1 of the file at (A, -A) -> PX = A, PY = +A; KM positive for ccw
    for i, (x, y, s) in enumerate([(A, -A, -1), (-A, -A, 1), (-A, A, -1), (A, A, 1)]):
        assert params[f"CA_ROTOR{i}_PX"][0] == pytest.approx(x, rel=1e-9)
        assert params[f"CA_ROTOR{i}_PY"][0] == pytest.approx(-y, rel=1e-9)
        assert params[f"CA_ROTOR{i}_KM"][0] == pytest.approx(-s * 0.006, rel=1e-6)
        assert params[f"SIM_GZ_EC_MAX{i + 1}"] == (3142, 6)  # round(30000 rpm in rad/s), INT32
        assert params[f"SIM_GZ_EC_MIN{i + 1}"] == (0, 6)
        assert params[f"SIM_GZ_EC_FUNC{i + 1}"] == (101 + i, 6)
    assert params["CA_ROTOR_COUNT"] == (4, 6)


def composite(model):
    """Total mass, CoM and inertia about the CoM of all links (each link's inertial pose: translation only)."""
    links = []
    for link in model.findall("link"):
        pose = np.array([float(x) for x in (link.findtext("pose") or "0 0 0 0 0 0").split()])[:3]
        inertial = link.find("inertial")
        ip = np.array([float(x) for x in (inertial.findtext("pose") or "0 0 0 0 0 0").split()])[:3]
        I = inertial.find("inertia")
        get = lambda k: float(I.findtext(k) or 0.0)  # noqa: E731
        J = np.array([[get("ixx"), get("ixy"), get("ixz")], [get("ixy"), get("iyy"), get("iyz")],
                      [get("ixz"), get("iyz"), get("izz")]])
        links.append((float(inertial.findtext("mass")), pose + ip, J))
    m = sum(mi for mi, _, _ in links)
    c = sum(mi * ci for mi, ci, _ in links) / m
    J = sum(Ji + mi * ((ci - c) @ (ci - c) * np.eye(3) - np.outer(ci - c, ci - c)) for mi, ci, Ji in links)
    return m, c, J


def test_the_links_together_have_the_vehicles_mass_cg_and_inertia(tmp_path):
    vehicle = load_vehicle(VEHICLES / "crazyflie21_brushless.yaml").with_changes(effects=[
        {"name": "cg_offset", "parameters": {"rx": 0.002, "ry": -0.001}},
        {"name": "mass_error", "parameters": {"dm": 0.002}},
        {"name": "motor_imbalance", "parameters": {"d1": 0.03, "d2": -0.02, "d3": 0.0, "d4": 0.01}},
        {"name": "rotor_drag", "parameters": {"k": 2e-7}},
        {"name": "blade_flapping", "parameters": {"k": 6.9e-4}}])
    save_vehicle(vehicle, tmp_path / "v.yaml")
    root, params = export(tmp_path / "v.yaml", tmp_path / "out")
    m, c, J = composite(root.find("model"))
    assert m == pytest.approx(0.039, rel=1e-9)
    assert c == pytest.approx([0.002, -0.001, 0.0], abs=1e-12)
    assert J == pytest.approx(np.diag([16.571710e-6, 16.655602e-6, 29.261652e-6]), abs=1e-14)  # 10 digits in the file
    d = [0.03, -0.02, 0.0, 0.01]
    for i, p in enumerate(plugins(root)):
        v = {e.tag: float(e.text) for e in p if e.tag.endswith(("Constant", "Coefficient"))}
        assert v["motorConstant"] == pytest.approx(CT * (1 + d[i]) / F**2, rel=1e-9)
        # the rotor's drag torque with its thrust relative to the others', as in qr: C_Q (1 + d_i - mean d) u²
        share = 1 + d[i] - sum(d) / 4
        assert v["momentConstant"] * v["motorConstant"] == pytest.approx(CQ * share / F**2, rel=1e-9)
        assert v["momentConstant"] == pytest.approx(CQ * share / (CT * (1 + d[i])), rel=1e-9)
        assert v["rotorDragCoefficient"] == pytest.approx(2e-7 / F, rel=1e-9)  # per rpm -> per rad/s
        assert v["rollingMomentCoefficient"] == 0  # flapping is not the rolling moment (a different axis)
        assert params[f"CA_ROTOR{i}_KM"][0] == pytest.approx(
            -[-1, 1, -1, 1][i] * CQ * share / (CT * (1 + d[i])), rel=1e-6)
    # PX4's positions are relative to the CG: x - rx, -(y - ry)
    assert params["CA_ROTOR0_PX"][0] == pytest.approx(A - 0.002, rel=1e-9)
    assert params["CA_ROTOR0_PY"][0] == pytest.approx(-(-A + 0.001), rel=1e-9)
    text = (tmp_path / "out" / "mapping.md").read_text()
    row = next(line for line in text.splitlines() if line.startswith("| blade_flapping"))
    assert "| impossible |" in row and "rollingMomentCoefficient" in row
