"""qr only ever removes or replaces what it wrote itself (issue 12, "Never lose a user's file").

Every refusal is one line, exit 2, before any work, and leaves every file as it was.  A killed
command (SIGTERM, SIGKILL) leaves the user's files as they were, and its temporaries are gone after
the next run of the same command.
"""

import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pandas as pd
import pytest

from conftest import ROOT, VEHICLES, run_cli
from conftest import small_flight as _flight

HB = VEHICLES / "asctec_hummingbird.yaml"
MARKER = ".qr-output.json"
SYNTH = ["synth", "--vehicle", HB, "--duration", "2"]
SYNTH_FILES = {"flight.csv", "vehicle.yaml", "truth.json", "truth.parquet"}
QR = ROOT / ".venv" / "bin" / "qr"


def snapshot(root: Path) -> dict:
    """Every file under ``root`` (hidden ones too, not qr's temporaries) with its bytes."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and ".qrtmp-" not in p.relative_to(root).as_posix()}


def temporaries(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if ".qrtmp-" in p.name]


def assert_refused(status, err, *phrases):
    lines = err.strip().splitlines()
    assert status == 2 and len(lines) == 1, err
    assert lines[0].startswith("qr: error: ") and "fix:" in lines[0], lines[0]
    for p in phrases:
        assert p in lines[0], (p, lines[0])


def users_folder(path: Path, flight: bool = False) -> Path:
    """A folder of the user's: notes, a table, a subfolder with a picture (and a flight.csv)."""
    path.mkdir()
    (path / "notes.txt").write_text("my notes\n")
    (path / "data.csv").write_text("a,b\n1,2\n")
    (path / "figures").mkdir()
    (path / "figures" / "mine.png").write_bytes(b"not qr's")
    if flight:
        _flight(300).to_csv(path / "flight.csv", index=False)
    return path


@pytest.fixture
def no_work(monkeypatch):
    """Reading or filtering a flight, or simulating one, fails the test: refusals come first."""
    import qr.estimation.crossfit
    import qr.flight
    import qr.sim.synth

    def work(*a, **k):
        raise AssertionError("work started before the output location was checked")

    monkeypatch.setattr(qr.flight, "read_flight", work)
    monkeypatch.setattr(qr.estimation.crossfit, "prepare_flight", work)
    monkeypatch.setattr(qr.sim.synth, "synthesize", work)


def _diagnose(flight):
    return ["diagnose", flight, "--vehicle", HB]


# ---- output folders: qr synth and qr diagnose ------------------------------------------------------

def test_a_new_folder_is_created_with_its_marker(tmp_path, capsys):
    status, _, err = run_cli([*SYNTH, "--out", tmp_path / "s"], capsys)
    assert status == 0, err
    assert {p.name for p in (tmp_path / "s").iterdir()} == SYNTH_FILES | {MARKER}
    marker = json.loads((tmp_path / "s" / MARKER).read_text())
    assert marker["tool"] == "qr" and marker["command"] == "qr synth" and marker["qr_version"]
    assert set(marker["files"]) == SYNTH_FILES
    assert not temporaries(tmp_path)


def test_an_empty_folder_is_used(tmp_path, capsys):
    (tmp_path / "s").mkdir()
    status, _, err = run_cli([*SYNTH, "--out", tmp_path / "s"], capsys)
    assert status == 0, err
    assert set(json.loads((tmp_path / "s" / MARKER).read_text())["files"]) == SYNTH_FILES
    assert {p.name for p in (tmp_path / "s").iterdir()} == SYNTH_FILES | {MARKER}


@pytest.mark.parametrize("command", ["synth", "diagnose"])
def test_a_folder_of_the_users_is_refused_untouched_before_any_work(command, tmp_path, capsys, no_work):
    out = users_folder(tmp_path / "mine", flight=True)
    (tmp_path / "f.csv").write_text("t\n")
    before = snapshot(tmp_path)
    args = SYNTH if command == "synth" else _diagnose(tmp_path / "f.csv")
    status, _, err = run_cli([*args, "--out", out], capsys)  # (no_work: any work before the refusal fails)
    assert_refused(status, err, "mine", "not empty (4 entries)", "not a previous qr output", "--force")
    assert snapshot(tmp_path) == before and not temporaries(tmp_path)


def test_force_writes_beside_the_users_files(tmp_path, capsys):
    out = users_folder(tmp_path / "mine")
    mine = snapshot(out)
    status, _, err = run_cli([*SYNTH, "--out", out, "--force"], capsys)
    assert status == 0, err
    after = snapshot(out)
    assert {k: after[k] for k in mine} == mine  # every file of the user's, byte for byte
    assert set(after) == set(mine) | SYNTH_FILES | {MARKER}
    assert set(json.loads(after[MARKER])["files"]) == SYNTH_FILES
    # the folder is now a qr output: the next run replaces qr's files only, without --force
    flight = after["flight.csv"]
    status, _, err = run_cli([*SYNTH, "--seed", "9", "--out", out], capsys)
    assert status == 0, err
    again = snapshot(out)
    assert {k: again[k] for k in mine} == mine and again["flight.csv"] != flight
    assert not temporaries(tmp_path)


def test_force_never_overwrites_a_users_file(tmp_path, capsys, no_work):
    out = users_folder(tmp_path / "mine", flight=True)  # its flight.csv: a name qr synth writes
    before = snapshot(tmp_path)
    status, _, err = run_cli([*SYNTH, "--out", out, "--force"], capsys)
    assert_refused(status, err, "mine/flight.csv", "did not write", "move it away")
    assert snapshot(tmp_path) == before and not temporaries(tmp_path)


def test_a_previous_output_is_replaced_and_the_users_additions_kept(tmp_path, capsys):
    out = tmp_path / "s"
    status, _, err = run_cli([*SYNTH, "--seed", "1", "--out", out], capsys)
    assert status == 0, err
    first = snapshot(out)
    (out / "my_notes.txt").write_text("added by the user\n")
    (out / "plots").mkdir()
    (out / "plots" / "p.png").write_bytes(b"mine")
    status, _, err = run_cli([*SYNTH, "--seed", "2", "--out", out], capsys)
    assert status == 0, err
    second = snapshot(out)
    assert second["my_notes.txt"] == b"added by the user\n" and second["plots/p.png"] == b"mine"
    assert second["flight.csv"] != first["flight.csv"]  # replaced: another seed
    assert set(json.loads(second[MARKER])["files"]) == SYNTH_FILES
    assert set(second) == SYNTH_FILES | {MARKER, "my_notes.txt", "plots/p.png"}


def test_a_diagnose_output_whose_file_names_clash_with_the_users_is_refused_before_work(tmp_path, capsys,
                                                                                       no_work):
    from qr.atomic import atomic_dir

    out = tmp_path / "d"
    with atomic_dir(out, command="qr synth") as tmp:  # a qr output (of another command)
        _write({"flight.csv": "t\n"})(tmp)
    (out / "report.md").write_text("my own report\n")  # the user's, where qr diagnose writes report.md
    (tmp_path / "f.csv").write_text("t\n")
    before = snapshot(tmp_path)
    status, _, err = run_cli([*_diagnose(tmp_path / "f.csv"), "--out", out], capsys)
    assert_refused(status, err, "d/report.md", "did not write")
    assert snapshot(tmp_path) == before


def _refusal_cases(tmp_path):
    """Inputs in data/in/ (a flight, a vehicle), the current folder work/, a file of the user's."""
    (tmp_path / "data" / "in").mkdir(parents=True)
    flight = tmp_path / "data" / "in" / "flight.csv"
    flight.write_text("t\n")
    shutil.copy(HB, tmp_path / "data" / "in" / "v.yaml")
    (tmp_path / "a_file").write_text("a file of the user's\n")
    return flight, {
        "dot": (".", "--out is the current folder"),
        "cwd_parent": ("..", "--out is the current folder (or holds it)"),
        "holds_input": (tmp_path / "data" / "in", "--out holds the input"),
        "holds_input_deeper": (tmp_path / "data", "--out holds the input"),
        "file_in_the_way": (tmp_path / "a_file", "a file is in the way of the output folder"),
        "missing_parent": (tmp_path / "nope" / "d", "does not exist"),
        "parent_is_a_file": (tmp_path / "a_file" / "d", "is not a folder"),
    }


CASES = ["dot", "cwd_parent", "holds_input", "holds_input_deeper", "file_in_the_way", "missing_parent",
         "parent_is_a_file"]


@pytest.mark.parametrize("command", ["synth", "diagnose"])
@pytest.mark.parametrize("case", CASES)
def test_unusable_out_is_refused_in_one_line_before_any_work(case, command, tmp_path, capsys, monkeypatch,
                                                             no_work):
    flight, cases = _refusal_cases(tmp_path)
    (tmp_path / "work").mkdir()
    monkeypatch.chdir(tmp_path / "work")  # "." and ".." are relative to here
    out, phrase = cases[case]
    before = snapshot(tmp_path)
    args = (["synth", "--vehicle", flight.parent / "v.yaml", "--duration", "2"] if command == "synth"
            else ["diagnose", flight, "--vehicle", flight.parent / "v.yaml"])
    status, _, err = run_cli([*args, "--out", out], capsys)  # (no_work: any work before the refusal fails)
    assert_refused(status, err, phrase)
    assert snapshot(tmp_path) == before and not temporaries(tmp_path)


def test_a_read_only_parent_is_refused(tmp_path):
    """Root writes anywhere: as root the command runs without the capabilities that override file
    permissions (``setpriv``), as a user would."""
    ro = tmp_path / "ro"
    ro.mkdir()
    os.chmod(ro, 0o555)
    prefix = []
    if os.geteuid() == 0:
        if not shutil.which("setpriv"):
            pytest.skip("running as root without setpriv: a read-only folder is writable here")
        prefix = ["setpriv", "--bounding-set", "-dac_override,-dac_read_search,-fowner"]
    try:
        p = subprocess.run([*prefix, QR, "synth", "--vehicle", HB, "--duration", "2", "--out", ro / "s"],
                           env={**os.environ, "QR_TRACKING": "off"}, capture_output=True, text=True, timeout=120)
        assert_refused(p.returncode, p.stderr, "ro/s", "is not writable")
        assert list(ro.iterdir()) == []
    finally:
        os.chmod(ro, 0o755)


# ---- output files: qr ingest and qr summary ----------------------------------------------------------

def test_ingest_never_replaces_an_existing_file_without_force(tmp_path, capsys, monkeypatch):
    src = tmp_path / "log.csv"
    _flight(300).to_csv(src, index=False)
    out = tmp_path / "flight.csv"
    out.write_text("the user's file\n")
    status, _, err = run_cli(["ingest", src, "--vehicle", HB, "--out", out], capsys)
    assert_refused(status, err, "flight.csv", "the file exists", "--force")
    assert out.read_text() == "the user's file\n"
    status, _, err = run_cli(["ingest", src, "--vehicle", HB, "--out", out, "--force"], capsys)
    assert status == 0, err
    assert len(pd.read_csv(out)) == 300
    # never the input itself, --force or not
    before = src.read_bytes()
    status, _, err = run_cli(["ingest", src, "--vehicle", HB, "--out", src, "--force"], capsys)
    assert_refused(status, err, "--out is an input")
    assert src.read_bytes() == before
    for bad, phrase in ((tmp_path, "a folder is in the way"), (tmp_path / "nope" / "f.csv", "does not exist"),
                        (tmp_path / "f.txt", ".csv or .parquet")):
        status, _, err = run_cli(["ingest", src, "--vehicle", HB, "--out", bad], capsys)
        assert_refused(status, err, phrase)
    assert not temporaries(tmp_path)


def test_summary_checks_both_of_its_files(tmp_path, capsys):
    src = tmp_path / "f1.csv"
    _flight(300).to_csv(src, index=False)
    (tmp_path / "sum.md").write_text("my markdown\n")  # the Markdown twin's name
    status, _, err = run_cli(["summary", src, "--vehicle", HB, "--out", tmp_path / "sum.csv"], capsys)
    assert_refused(status, err, "sum.md", "the file exists")
    assert not (tmp_path / "sum.csv").exists() and (tmp_path / "sum.md").read_text() == "my markdown\n"
    status, _, err = run_cli(["summary", src, "--vehicle", HB, "--out", tmp_path / "sum.csv", "--force"], capsys)
    assert status == 0, err
    assert (tmp_path / "sum.md").read_text() != "my markdown\n" and len(pd.read_csv(tmp_path / "sum.csv")) == 1


# ---- the mechanism: atomic_dir and atomic_path ---------------------------------------------------------

def _write(files: dict):
    def fill(tmp: Path):
        for rel, text in files.items():
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            (tmp / rel).write_text(text)
    return fill


def test_replacing_an_output_removes_only_qr_files_no_longer_written(tmp_path):
    from qr.atomic import atomic_dir

    out = tmp_path / "o"
    with atomic_dir(out) as tmp:
        _write({"a.txt": "a1", "sub/b.txt": "b1", "old.txt": "o1"})(tmp)
    (out / "user.txt").write_text("u")
    with atomic_dir(out) as tmp:
        _write({"a.txt": "a2", "sub/b.txt": "b2"})(tmp)
    assert snapshot(out) | {MARKER: b""} == {"a.txt": b"a2", "sub/b.txt": b"b2", "user.txt": b"u", MARKER: b""}
    assert json.loads((out / MARKER).read_text())["files"] == ["a.txt", "sub/b.txt"]


def test_a_users_file_appearing_during_the_work_is_not_overwritten(tmp_path):
    from qr.atomic import atomic_dir
    from qr.errors import QrInputError

    out = tmp_path / "o"
    with atomic_dir(out) as tmp:
        _write({"a.txt": "a1"})(tmp)
    before = None
    with pytest.raises(QrInputError, match="b.txt: qr did not write this file"):
        with atomic_dir(out) as tmp:
            _write({"a.txt": "a2", "b.txt": "b2"})(tmp)
            (out / "b.txt").write_text("the user's")  # while qr works
            before = snapshot(out)
    assert snapshot(out) == before  # nothing moved: a.txt is still the old one
    assert (out / "a.txt").read_text() == "a1" and not temporaries(tmp_path)


def test_an_output_stays_recognisably_qrs_when_moving_its_files_fails_halfway(tmp_path, monkeypatch):
    """A crash between the moves: the marker already lists old and new files, so nothing of the
    output is taken for the user's, and the next run completes it."""
    import qr.atomic
    from qr.atomic import atomic_dir

    out = tmp_path / "o"
    with atomic_dir(out) as tmp:
        _write({"a.txt": "a1", "old.txt": "o1"})(tmp)
    (out / "user.txt").write_text("u")
    real, moves = os.replace, []

    def crash_on_second_move(src, dst):
        if ".qrtmp-" in str(src) and Path(dst).parent.name == "o" and Path(dst).name != MARKER:
            moves.append(dst)
            if len(moves) == 2:
                raise OSError("the disk is gone")
        return real(src, dst)

    monkeypatch.setattr(qr.atomic.os, "replace", crash_on_second_move)
    with pytest.raises(OSError, match="the disk is gone"):
        with atomic_dir(out) as tmp:
            _write({"a.txt": "a2", "new.txt": "n2"})(tmp)
    monkeypatch.setattr(qr.atomic.os, "replace", real)
    listed = json.loads((out / MARKER).read_text())["files"]
    assert set(listed) == {"a.txt", "new.txt", "old.txt"}  # the union, while half moved
    assert (out / "user.txt").read_text() == "u"
    with atomic_dir(out) as tmp:  # the next run: no --force needed, user.txt untouched
        _write({"a.txt": "a3", "new.txt": "n3"})(tmp)
    assert snapshot(out) | {MARKER: b""} == {"a.txt": b"a3", "new.txt": b"n3", "user.txt": b"u", MARKER: b""}
    assert not temporaries(tmp_path)


def test_a_marker_cannot_make_qr_remove_files_outside_its_folder(tmp_path):
    from qr.atomic import atomic_dir

    out = tmp_path / "o"
    out.mkdir()
    (tmp_path / "precious.txt").write_text("keep")
    (out / MARKER).write_text(json.dumps({"tool": "qr", "files": ["../precious.txt", "/etc/hostname", "x"]}))
    with atomic_dir(out) as tmp:
        _write({"y": "y"})(tmp)
    assert (tmp_path / "precious.txt").read_text() == "keep"


def test_atomic_writes_fsync_the_file_before_and_the_folder_after_the_rename(tmp_path, monkeypatch):
    import qr.atomic
    from qr.atomic import atomic_dir, write_text

    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        return real_fsync(fd)

    def replace(src, dst):
        events.append(("replace", str(src), str(dst)))
        return real_replace(src, dst)

    monkeypatch.setattr(qr.atomic.os, "fsync", fsync)
    monkeypatch.setattr(qr.atomic.os, "replace", replace)
    dest = tmp_path / "t.txt"
    write_text(dest, "x")
    (i_rename, ev), = [(i, e) for i, e in enumerate(events) if e[0] == "replace"]
    tmp = ev[1]
    assert ev[2] == str(dest)
    assert ("fsync", tmp) in events[:i_rename]  # the data is on disk before the name points at it
    assert ("fsync", str(tmp_path)) in events[i_rename + 1:]  # and the new name is on disk after
    events.clear()
    with atomic_dir(tmp_path / "d") as t:
        (t / "f").write_text("y")
    i_rename = next(i for i, e in enumerate(events) if e[0] == "replace" and e[2] == str(tmp_path / "d"))
    assert ("fsync", str(t / "f")) in events[:i_rename]
    assert ("fsync", str(tmp_path)) in events[i_rename + 1:]


# ---- killed commands -----------------------------------------------------------------------------

def _start_killable(out: Path, log: Path):
    """``qr synth`` into ``out`` (an existing output), long enough to be killed while it works (an hour of
    flight: it is killed as soon as it has begun, so its length costs nothing and leaves any machine time)."""
    env = {**os.environ, "QR_TRACKING": "off"}
    with open(log, "w") as err:
        p = subprocess.Popen([QR, "synth", "--vehicle", HB, "--duration", "3600", "--seed", "3", "--out", out],
                             env=env, stdout=subprocess.DEVNULL, stderr=err)
    hang_guard = time.monotonic() + 1800  # only against a hang: no assertion is about time
    while not temporaries(out.parent):  # the temporary folder exists: the work has begun
        assert p.poll() is None, log.read_text()
        if time.monotonic() > hang_guard:
            pytest.fail(f"qr synth has not begun its work in 30 min: {log.read_text()}")
        time.sleep(0.02)
    return p


@pytest.fixture
def previous_output(tmp_path, capsys):
    out = tmp_path / "s"
    status, _, err = run_cli([*SYNTH, "--out", out], capsys)
    assert status == 0, err
    (out / "my_notes.txt").write_text("the user's\n")
    return out


def test_sigterm_ends_a_command_cleanly_without_temporaries(previous_output, tmp_path):
    before = snapshot(previous_output)
    p = _start_killable(previous_output, tmp_path / "err.log")
    p.send_signal(signal.SIGTERM)
    assert p.wait(timeout=60) == 128 + signal.SIGTERM
    assert "qr: terminated" in (tmp_path / "err.log").read_text()
    assert snapshot(previous_output) == before and not temporaries(tmp_path)


def test_sigkill_leftovers_are_removed_by_the_next_run_of_the_command(previous_output, tmp_path):
    before = snapshot(previous_output)
    p = _start_killable(previous_output, tmp_path / "err.log")
    p.kill()
    assert p.wait(timeout=60) == -signal.SIGKILL
    assert temporaries(tmp_path)  # nothing could clean up ...
    assert snapshot(previous_output) == before  # ... and nothing of the output was touched
    p = subprocess.run([QR, "synth", "--vehicle", HB, "--duration", "4", "--seed", "3", "--out", previous_output],
                       env={**os.environ, "QR_TRACKING": "off"}, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert not temporaries(tmp_path)
    assert (previous_output / "my_notes.txt").read_text() == "the user's\n"
    assert len(pd.read_csv(previous_output / "flight.csv")) == 401  # the new output, whole
