"""``qr diagnose`` keeps the contract exactly as written (../shared/spec/diagnosis.md, issue 12).

The spec's command line, literally, through a subprocess: overrides after ``--out``; ``flights``
as the user gave them; ``split`` on each flight file's own ``t`` axis; strictly valid JSON.  Plus
the pieces: the residual-anatomy table at the noise floor, and the override an error suggests.
"""

import json
import math
import os
import re
import subprocess

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT, VEHICLES, run_cli
from conftest import small_flight as _flight

HB = VEHICLES / "asctec_hummingbird.yaml"
QR = ROOT / ".venv" / "bin" / "qr"
SHIFT = 100.0  # the second flight's clock starts here (a log cut from a longer recording)


def _strict(text):
    def refuse(name):
        raise ValueError(f"bare {name} in JSON")
    return json.loads(text, parse_constant=refuse)


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    """Two 20 s flights, both named flight.csv, in two folders; the second one's t starts at 100 s."""
    from qr.sim.synth import SynthConfig, write_synth
    from qr.vehicle import load_vehicle

    root = tmp_path_factory.mktemp("contract")
    for name, seed in (("a", 1), ("b", 2)):
        write_synth(root / name, load_vehicle(HB), [{"name": "linear_drag", "parameters": {"kx": 0.3, "ky": 0.3,
                                                                                          "kz": 0.1}}],
                    SynthConfig(duration=20, rate=100, seed=seed))
    b = pd.read_csv(root / "b" / "flight.csv")
    b["t"] += SHIFT
    b.to_csv(root / "b" / "flight.csv", index=False, float_format="%.9g")
    (root / "a" / "vehicle.yaml").rename(root / "v.yaml")
    cmd = [QR, "diagnose", "a/flight.csv", "b/flight.csv", "--vehicle", "v.yaml", "--out", "d",
           "diagnose.horizon_s=0.5"]
    p = subprocess.run(cmd, cwd=root, env={**os.environ, "QR_TRACKING": "off"}, capture_output=True, text=True,
                       timeout=600)
    assert p.returncode == 0, p.stderr
    return root, p


def test_overrides_after_out_take_effect(diagnosed):
    root, _ = diagnosed
    doc = _strict((root / "d" / "diagnosis.json").read_text())
    assert doc["config"]["horizon_s"] == 0.5 and doc["replay"]["horizon_s"] == 0.5
    assert "restarted every 0.5 s" in (root / "d" / "report.md").read_text()


def test_flights_are_listed_as_given(diagnosed):
    root, _ = diagnosed
    doc = _strict((root / "d" / "diagnosis.json").read_text())
    assert doc["flights"] == ["a/flight.csv", "b/flight.csv"]


def test_split_is_on_each_flight_files_own_time_axis(diagnosed):
    root, _ = diagnosed
    doc = _strict((root / "d" / "diagnosis.json").read_text())
    cfg = doc["config"]
    windows = doc["split"]["per_flight"]
    assert doc["split"]["train"] == windows[0]["train"] and doc["split"]["test"] == windows[0]["test"]
    for name, w in zip("ab", windows):
        t = pd.read_csv(root / name / "flight.csv")["t"].to_numpy()
        t0, t1 = t[0] + cfg["trim_s"], t[-1] - cfg["trim_s"]  # trimmed ends, in the file's t
        cut = t0 + cfg["train_fraction"] * (t1 - t0)
        expected = [t0, cut - cfg["gap_s"] / 2, cut + cfg["gap_s"] / 2, t1]
        np.testing.assert_allclose(w["train"] + w["test"], expected, atol=0.011)  # one sample at 100 Hz
    assert windows[1]["train"][0] == pytest.approx(SHIFT + 0.5, abs=0.011)


def test_output_is_strict_json_and_qrs_marker_lists_every_file(diagnosed):
    root, _ = diagnosed
    out = root / "d"
    doc = _strict((out / "diagnosis.json").read_text())
    marker = json.loads((out / ".qr-output.json").read_text())
    on_disk = {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()} - {".qr-output.json"}
    assert marker["command"] == "qr diagnose" and set(marker["files"]) == on_disk
    assert {"diagnosis.json", "report.md", "extended_vehicle.yaml"} <= on_disk
    # anatomy: a share, or null (with the note saying why); never a number divided by a clamped floor
    shares = [x for v in doc["anatomy"].values() for x in v]
    assert all(x is None or abs(x) < 1e3 for x in shares), doc["anatomy"]
    if None in shares:
        assert any(n.startswith("anatomy: null") for n in doc["notes"])
    report = (out / "report.md").read_text()
    assert not re.search(r"e\+\d\d", report), "a number like 1e+297 in the report"


def test_the_override_an_error_suggests_works_after_out(tmp_path, capsys, monkeypatch):
    import qr.estimation.crossfit
    from qr.diagnose.diagnosis import Settings

    path = tmp_path / "short.csv"
    _flight(1400).to_csv(path, index=False)  # 14 s: too short for 5 folds of 2 s blocks
    out = tmp_path / "d"
    status, _, err = run_cli(["diagnose", path, "--vehicle", HB, "--out", out], capsys)
    assert status == 2 and "too short to hold out a test part" in err
    suggested = re.search(r"add (diagnose\.block_s=[0-9.]+) at the end of the command", err)
    assert suggested, err
    # the suggestion, appended to the same command line, passes that check (and reaches the filter)
    seen = {}
    composed = Settings.composed

    def record(overrides):
        seen["settings"] = composed(overrides)
        return seen["settings"]

    def stop(*a, **k):
        raise RuntimeError("reached the filter")

    monkeypatch.setattr(Settings, "composed", staticmethod(record))
    monkeypatch.setattr(qr.estimation.crossfit, "prepare_flight", stop)
    with pytest.raises(RuntimeError, match="reached the filter"):
        run_cli(["diagnose", path, "--vehicle", HB, "--out", out, suggested[1], "filter=auto"], capsys)
    assert seen["settings"].diagnose.block_s == float(suggested[1].split("=")[1])
    assert seen["settings"].filter["name"] == "auto" and not out.exists()


def test_anatomy_shares_only_what_is_above_the_noise_floor(monkeypatch):
    """Hand-made held-out residuals with noise sd 1 on every axis: axis 0 carries a signal (variance
    9, of which 8 above noise), axis 1 is exactly noise, axis 2 is 4 % above noise (within the
    floor's margin), axis 3 is 21 % above.  The candidate predicts [2, -2, ...] on axes 0 and 3."""
    from qr.diagnose import held_out

    y = np.array([[3, 1, 1.02, 1.1, 0, 0], [-3, -1, -1.02, -1.1, 0, 0]] * 2, dtype=float)
    pred = np.zeros_like(y)
    pred[:, 0] = pred[:, 3] = [2, -2, 2, -2]
    monkeypatch.setattr(held_out, "fit", lambda stats, named: np.zeros(1))
    monkeypatch.setattr(held_out, "predict", lambda s, vehicle, named, theta, force_only=(): pred)
    shares = np.array(held_out.anatomy(None, None, y, np.ones_like(y), None, ["linear_drag"])["linear_drag"])
    # axis 0: gain = 9 - mean((y - pred)^2) = 9 - 1 = 8 of 8 above noise: all of it
    assert shares[0] == pytest.approx(1.0)
    # axis 3: gain = 1.21 - 0.81 = 0.40 against 0.21 above noise
    assert shares[3] == pytest.approx((1.21 - (1.1 - 2) ** 2) / 0.21)
    assert np.isnan(shares[[1, 2, 4, 5]]).all()


def test_report_shows_a_dash_at_the_noise_floor_and_json_says_null_and_why():
    from qr.diagnose.document import note_nulls
    from qr.diagnose.report import _anatomy_table

    lines = _anatomy_table({"linear_drag": [0.8, math.nan, 0.001, -0.3, math.nan, math.nan],
                            "cg_offset": [0.1, math.nan, math.nan, 0.9, math.nan, math.nan]})
    rows = [r for r in lines if r.startswith("| `")]
    assert rows[0] == "| `cg_offset` | 0.10 | – | – | 0.90 | – | – |"  # best share first
    assert rows[1] == "| `linear_drag` | 0.80 | – | 0 | -0.30 | – | – |"
    assert "– = the axis is at the noise floor" in lines[0]
    assert _anatomy_table({"x": [math.nan] * 6})[0].startswith("Residual anatomy: every axis's held-out residual "
                                                                "is at the noise floor")
    doc = note_nulls({"anatomy": {"x": [0.5, math.nan]}, "replay": {"nominal_position_rmse": math.inf}, "n": 1})
    assert doc["anatomy"]["x"] == [0.5, None] and doc["replay"]["nominal_position_rmse"] is None
    assert doc["notes"][0].startswith("anatomy: null for an axis whose held-out residual is at the noise floor")
    assert "replay.nominal_position_rmse" in doc["notes"][1]
    assert note_nulls({"n": 1.5}) == {"n": 1.5}  # nothing to say: no notes


def test_write_json_is_strict_for_everyone(tmp_path):
    from qr.atomic import write_json

    write_json(tmp_path / "x.json", {"a": math.nan, "b": [1.0, -math.inf, {"c": math.inf}], "d": np.float64(2.5)})
    assert _strict((tmp_path / "x.json").read_text()) == {"a": None, "b": [1.0, None, {"c": None}], "d": 2.5}


def _verdict_numbers(doc):
    """Every number the verdict states, checked against the numbers diagnosis.json holds."""
    import re

    v = doc["verdict"]
    named = [e["name"] for e in doc["effects"]]
    nom, ext = doc["losses"]["nominal"], doc["losses"]["extended"]
    if not doc["described"]:
        m = re.search(r"held-out residual is (\d+) % of the weight in force and (\d+) % of the weight's torque at the "
                      r"arm \(a rigid-body model leaves under (\d+) %\)", v)
        mf = doc["misfit"]
        assert m and int(m[1]) == round(100 * mf["force_of_weight"]) and int(m[2]) == round(
            100 * mf["torque_of_weight_at_arm"]) and int(m[3]) == round(100 * mf["limit"]), v
        assert mf["force_of_weight"] > mf["limit"] or mf["torque_of_weight_at_arm"] > mf["limit"]
        assert len(named) <= 1  # the largest effect at most, said before the flight is said not described
        for e in doc["effects"]:
            m = re.match(r"Identified (\w+) \((.*?)\), which alone removes (-?[\d.]+) % of the held-out residual\. "
                         r"The model does not describe", v)
            assert m and m[1] == e["name"] and float(m[3]) == pytest.approx(100 * e["explained_fraction"], abs=0.5)
            for k, val in e["parameters"].items():
                assert f"{k} = {val:.3g} ± {e['stderr'][k]:.2g}" in m[2], (k, m[2])
    elif named:
        m = re.search(r"Named (.*?); the extended model removes (-?[\d.]+) % of the nominal model's weighted held-out "
                      r"residual variance \(now ([\d.]+) x the noise floor's variance\); (.*)\.", v)
        assert m and m[1].split(", ") == named, v
        assert float(m[2]) == pytest.approx(100 * (1 - ext / nom), abs=0.5) and float(m[3]) == pytest.approx(ext, abs=0.006), (v, nom, ext)
        assert "100" not in m[2] or ext == 0, v  # never "removes 100 %" while a residual is left
        ratios = np.array(doc["extended"]["force_rmse"] + doc["extended"]["torque_rmse"]) / np.array(
            doc["noise_floor"]["force_rmse"] + doc["noise_floor"]["torque_rmse"])
        said = [float(x) for x in re.findall(r"\(([\d.]+) x\)", m[4])]
        assert said == pytest.approx([r for r in ratios if r > 1.5], abs=0.051), (m[4], ratios)
    else:
        m = re.search(r"Nothing named: (.*) \(weighted residual ([\d.]+) x the noise floor's variance", v)
        assert m and float(m[2]) == pytest.approx(nom, abs=0.006)
        assert ("up to noise" in m[1]) == (nom < 2)
    for c in doc["vehicle_file"]:  # "looks xF too large/small": F the stated factor's size
        m = re.search(r"looks x([\d.]+) too (large|small)", c["statement"])
        f = c["factor"]
        assert m and float(m[1]) == pytest.approx(f if f > 1 else 1 / f, rel=0.05) and (m[2] == "small") == (f > 1)
        assert c["statement"][0].upper() + c["statement"][1:] in v


@pytest.mark.parametrize("case", ["named", "nothing", "not described", "vehicle file"])
def test_every_number_the_verdict_states_is_the_documents(case, tmp_path, capsys):
    """The verdict (report.md's first line, `qr diagnose`'s last) is built from the numbers it states:
    read back, each equals diagnosis.json's own (losses, misfit shares, factors, names)."""
    import json

    import yaml

    from conftest import VEHICLES, run_cli

    effects = {"named": ["--effect", "linear_drag:kx=0.3,ky=0.3,kz=0.15"], "nothing": [],
               "not described": ["--effect", "linear_drag:kx=0.3,ky=0.3,kz=0.15"], "vehicle file": []}[case]
    assert run_cli(["synth", "--vehicle", VEHICLES / "asctec_hummingbird.yaml", "--duration", "40", "--seed", "5",
                    *effects, "--out", tmp_path / "s"], capsys)[0] == 0
    flight, vehicle, extra = tmp_path / "s" / "flight.csv", tmp_path / "s" / "vehicle.yaml", []
    if case == "not described":  # written scalar-last, the check skipped: the model cannot describe it
        import pandas as pd

        df = pd.read_csv(flight)
        df[["qw", "qx", "qy", "qz"]] = df[["qx", "qy", "qz", "qw"]].to_numpy()
        df.to_csv(flight, index=False)
        extra = ["diagnose.skip_checks=[thrust_axis,rotor_layout]"]
    if case == "vehicle file":  # the file's C_T 1.8 x the true one
        raw = yaml.safe_load(vehicle.read_text())
        raw["thrust_coeff"] *= 1.8
        vehicle = tmp_path / "ct.yaml"
        vehicle.write_text(yaml.safe_dump(raw))
    status, _, err = run_cli(["diagnose", flight, "--vehicle", vehicle, "--out", tmp_path / "d", *extra], capsys)
    assert status == 0, err
    doc = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    assert doc["described"] == (case != "not described")
    assert bool(doc["vehicle_file"]) == (case == "vehicle file")
    _verdict_numbers(doc)
    assert f"**{doc['verdict']}**" in (tmp_path / "d" / "report.md").read_text()
