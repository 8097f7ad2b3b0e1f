"""`qr export`: the spec's command line through a subprocess, its files and mapping.md, bad input.

docs/spec/export.md: ``qr export VEHICLE.yaml --to rotorpy|px4-gz|mujoco --out OUTDIR`` writes the
simulator's files and OUTDIR/mapping.md (every parameter and named effect: key, value, exact /
approximate / impossible); exit 0 when written, 2 with one line on standard error for unusable input;
nothing half-written; a file qr did not write is never replaced.
"""

import shutil
import subprocess
import sys

import pytest

from conftest import ROOT, VEHICLES, run_cli
from qr.vehicle import load_vehicle

EXTENDED = ROOT / "tests" / "export" / "crazyflie21_brushless_extended.yaml"
WRITES = {"rotorpy": ["crazyflie21_brushless_params.py"], "mujoco": ["crazyflie21_brushless.xml"],
          "px4-gz": ["crazyflie21_brushless/model.config", "crazyflie21_brushless/model.sdf",
                     "crazyflie21_brushless.params"]}
QR = shutil.which("qr") or str(ROOT / ".venv" / "bin" / "qr")


@pytest.mark.parametrize("to", sorted(WRITES))
def test_the_spec_command_line_writes_the_simulators_files_and_mapping_md(to, tmp_path):
    out = tmp_path / "OUTDIR"
    res = subprocess.run([QR, "export", str(EXTENDED), "--to", to, "--out", str(out)], capture_output=True,
                         text=True, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    for rel in [*WRITES[to], "mapping.md"]:
        assert (out / rel).is_file(), rel
    text = (out / "mapping.md").read_text()
    rows = [line for line in text.splitlines() if line.startswith("| ") and not line.startswith("| qr item")]
    statuses = [line.split(" | ")[5] for line in rows]  # qr item, qr value, key, value, formula, mapping, note
    assert set(statuses) <= {"exact", "approximate", "impossible"}
    # every parameter and named effect has its row
    for item in ["mass", "inertia", "thrust_coeff", "torque_coeff", "rotor_speed_unit",
                 *(e["name"] for e in load_vehicle(EXTENDED).effects)]:
        assert any(line.startswith(f"| {item} ") for line in rows), (to, item)
    counts = {s: statuses.count(s) for s in ("exact", "approximate", "impossible")}
    assert (f"{len(rows)} items: {counts['exact']} exact, {counts['approximate']} approximate, "
            f"{counts['impossible']} impossible") in text


def test_the_rotorpy_module_builds_rotorpys_multirotor(tmp_path):
    pytest.importorskip("rotorpy")
    import simulators as S
    from rotorpy.vehicles.multirotor import Multirotor

    assert run_cli_ok(["export", EXTENDED, "--to", "rotorpy", "--out", tmp_path / "rp"])
    mod = S.load_module(tmp_path / "rp" / "crazyflie21_brushless_params.py")
    plain, ours = Multirotor(mod.quad_params), mod.QrMultirotor()
    assert isinstance(ours, Multirotor) and plain.mass == ours.mass == 0.037
    # RotorPy's own example parameter files have these keys; the export has each of them
    from rotorpy.vehicles.hummingbird_params import quad_params as theirs

    assert set(theirs) <= set(mod.quad_params)


def run_cli_ok(args):
    from qr.cli import main

    return main([str(a) for a in args]) == 0


def test_python_m_qr_export_is_qr_export(tmp_path):
    res = subprocess.run([sys.executable, "-m", "qr.export", "crazyflie21_brushless", "--to", "mujoco", "--out",
                          str(tmp_path / "m")], capture_output=True, text=True, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "m" / "crazyflie21_brushless.xml").is_file()


def test_help_names_the_three_simulators_and_mapping_md():
    res = subprocess.run([QR, "export", "--help"], capture_output=True, text=True)
    assert res.returncode == 0
    for word in ("rotorpy", "px4-gz", "mujoco", "mapping.md", "VEHICLE.yaml", "--out", "QrMultirotor"):
        assert word in res.stdout, word


def rejected(capsys, args, *phrases):
    status, _, err = run_cli(["export", *args], capsys)
    lines = err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and lines[0].startswith("qr: error: ") and "fix:" in lines[0], err
    for p in phrases:
        assert p in lines[0], (p, lines[0])


def test_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path, capsys):
    out = tmp_path / "out"
    rejected(capsys, [VEHICLES / "crazyflie21_brushless.yaml", "--to", "gazebo", "--out", out], "unknown simulator",
             "rotorpy, px4-gz, mujoco")
    rejected(capsys, [tmp_path / "nope.yaml", "--to", "mujoco", "--out", out], "does not exist")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nmass: 0.037\n")
    rejected(capsys, [bad, "--to", "rotorpy", "--out", out], "lacks key")
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]


def test_never_replaces_a_file_it_did_not_write(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    mine = out / "mapping.md"
    mine.write_text("my notes")
    rejected(capsys, [VEHICLES / "crazyflie21_brushless.yaml", "--to", "mujoco", "--out", out], "not empty")
    status, _, err = run_cli(["export", VEHICLES / "crazyflie21_brushless.yaml", "--to", "mujoco", "--out", out,
                              "--force"], capsys)
    assert status == 2 and "would have to replace" in err and mine.read_text() == "my notes"
    assert not (out / "crazyflie21_brushless.xml").exists()  # nothing half-written
    # its own output folder it writes again (a second target beside the first, then the first again)
    new = tmp_path / "sims"
    for to in ("mujoco", "rotorpy", "mujoco"):
        assert run_cli(["export", VEHICLES / "crazyflie21_brushless.yaml", "--to", to, "--out", new], capsys)[0] == 0


@pytest.mark.parametrize("to", sorted(WRITES))
def test_the_library_builds_every_file_in_memory_and_the_stage_writes_exactly_them(to, tmp_path):
    """``qr.export.run`` writes nothing and returns a frozen Export; ``qr export`` writes its files (a hybrid's
    network weights among them) and mapping.md of it, byte for byte, and nothing else."""
    import dataclasses

    import simulators as S
    from qr import __version__
    from qr.export import run
    from qr.export.document import files
    from qr.stages.export import run_export

    path = S.hybrid_file(load_vehicle(EXTENDED), tmp_path / "hybrid", remainder=2e-6)
    before = sorted(tmp_path.rglob("*"))
    result = run(load_vehicle(path), path, to, __version__)
    assert sorted(tmp_path.rglob("*")) == before  # nothing written
    with pytest.raises(dataclasses.FrozenInstanceError):
        result.files = ()
    out = tmp_path / "out"
    written = run_export(path, to, out)
    assert written == [out / n.rstrip("/") for n in [*result.entries, "mapping.md"]]
    on_disk = {p.relative_to(out).as_posix(): p.read_bytes() for p in out.rglob("*")
               if p.is_file() and p.name != ".qr-output.json"}
    expected = {f.name: f.data.encode() if isinstance(f.data, str) else f.data for f in files(result)}
    assert on_disk == expected
    assert ("crazyflie21_brushless_residual.npz" in expected) == (to != "px4-gz")  # the network beside its module
