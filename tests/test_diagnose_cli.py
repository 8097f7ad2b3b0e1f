"""`qr diagnose` on unusable input: one line naming the file, the problem and the fix; exit 2; nothing written."""

import numpy as np
import pytest

from conftest import VEHICLES, run_cli
from test_flight_io import _flight

HB = VEHICLES / "asctec_hummingbird.yaml"


def assert_rejected(capsys, tmp_path, args, *phrases):
    out = tmp_path / "diag"
    status, _, err = run_cli(["diagnose", *args, "--vehicle", HB, "--out", out], capsys)
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("qr: error: ") and "fix:" in lines[0], err
    for p in phrases:
        assert p in lines[0], (p, lines[0])
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".diag")]  # no temporary left behind


def test_missing_flight(tmp_path, capsys):
    assert_rejected(capsys, tmp_path, [tmp_path / "nope.csv"], "does not exist", "nope.csv")


def test_bad_column(tmp_path, capsys):
    path = tmp_path / "bad.csv"
    _flight(3000).drop(columns="qz").to_csv(path, index=False)
    assert_rejected(capsys, tmp_path, [path], "missing column(s) 'qz'", "bad.csv")


def test_too_short_to_hold_out(tmp_path, capsys):
    path = tmp_path / "short.csv"
    _flight(500).to_csv(path, index=False)  # 5 s
    assert_rejected(capsys, tmp_path, [path], "too short to hold out a test part", "short.csv")


@pytest.mark.parametrize("override, phrase", [("diagnose.horizon=2", "horizon"),
                                              ("filter=nonexistent", "nonexistent")])
def test_bad_override(override, phrase, tmp_path, capsys):
    path = tmp_path / "ok.csv"
    _flight(6000).to_csv(path, index=False)
    assert_rejected(capsys, tmp_path, [path, override], phrase)


def test_rotor_speeds_in_the_wrong_unit(tmp_path, capsys):
    path = tmp_path / "units.csv"
    df = _flight(6000)
    df[["u1", "u2", "u3", "u4"]] *= 2 * np.pi / 60
    df.to_csv(path, index=False)
    assert_rejected(capsys, tmp_path, [path], "unit or coefficient error")
