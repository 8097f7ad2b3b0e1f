"""`qr diagnose` on unusable input: one line naming the file, the problem and the fix; exit 2; nothing written."""

import numpy as np
import pytest

from conftest import VEHICLES, run_cli
from conftest import small_flight as _flight

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


@pytest.mark.parametrize("override, phrases", [
    ("diagnose.horizon_s=abc", ["diagnose.horizon_s: 'abc' is not a number", "a number > 0"]),
    ("diagnose.horizon_s=-1", ["diagnose.horizon_s: -1 is out of range: it must be a number > 0"]),
    ("diagnose.train_fraction=1.5", ["diagnose.train_fraction: 1.5 is out of range", "a number in (0, 1)",
                                     "e.g. diagnose.train_fraction=0.7 (the default"]),
    ("diagnose.block_s=0", ["diagnose.block_s: 0 is out of range: it must be a number > 0"]),
    ("diagnose.gap_s=-1", ["diagnose.gap_s: -1 is out of range: it must be a number >= 0"]),
    ("diagnose.trim_s=nan", ["diagnose.trim_s: nan is out of range"]),
    ("diagnose.delay_max_s=0.5", ["diagnose.delay_max_s: 0.5 is out of range: it must be a number in (0, 0.1]"]),
    ("diagnose.selection.folds=0", ["diagnose.selection.folds: 0 is out of range: it must be an integer >= 2"]),
    ("diagnose.selection.folds=2.5", ["diagnose.selection.folds: 2.5 is not an integer"]),
    ("diagnose.selection.bootstrap=0", ["diagnose.selection.bootstrap: 0 is out of range"]),
    ("diagnose.selection.min_gain=true", ["diagnose.selection.min_gain: true is not a number", "in [0, 1)"]),
    ("diagnose.candidates=[linear_drg]", ["diagnose.candidates: unknown name(s) 'linear_drg'",
                                          "did you mean 'linear_drag'?", "blade_flapping"]),
    ("diagnose.candidates=linear_drag", ["diagnose.candidates: 'linear_drag' is not a list (write [linear_drag])"]),
    ("diagnose.candidates=[]", ["diagnose.candidates: the list is empty", "or null (the whole catalog)"]),
    ("diagnose.exclude=[foo]", ["diagnose.exclude: unknown name(s) 'foo'"]),
    ("diagnose.remainder_inputs=[a_b]", ["'a_b' is not allowed: the residual f_a is computed from it"]),
    ("filter.tune.grid=abc", ["filter.tune.grid: 'abc' is not an integer", "an integer >= 3"]),
    ("filter.nis.confidence=1.5", ["filter.nis.confidence: 1.5 is out of range: it must be a number in (0, 1)"]),
    ("filter.nis.burn_in_s=nan", ["filter.nis.burn_in_s: nan is out of range"]),
])
def test_override_of_wrong_type_or_out_of_range(override, phrases, tmp_path, capsys):
    path = tmp_path / "ok.csv"
    _flight(3000).to_csv(path, index=False)
    assert_rejected(capsys, tmp_path, [path, override], *phrases)


def test_every_exclusion_leaves_nothing(tmp_path, capsys):
    from qr.effects import CATALOG

    path = tmp_path / "ok.csv"
    _flight(3000).to_csv(path, index=False)
    assert_rejected(capsys, tmp_path, [path, "diagnose.candidates=[linear_drag,cg_offset]",
                                       "diagnose.exclude=[linear_drag,cg_offset]"],
                    "diagnose.exclude: [linear_drag,cg_offset] leaves no candidate effect to test")
    assert len(CATALOG) > 2


def test_every_setting_declares_its_range():
    """A new setting without its allowed values would go unchecked: each field declares them."""
    from dataclasses import fields

    from qr.diagnose.settings import DiagnoseConfig
    from qr.identification.selection import SelectionConfig

    for cls in (DiagnoseConfig, SelectionConfig):
        for f in fields(cls):
            assert f.name == "selection" or "allowed" in f.metadata, (cls.__name__, f.name)


def test_defaults_file_is_within_the_ranges():
    from qr.config import compose, to_dict
    from qr.diagnose.settings import DiagnoseConfig

    cfg = DiagnoseConfig.from_dict(to_dict(compose([]).diagnose))
    assert cfg == DiagnoseConfig()  # conf/diagnose/default.yaml and the dataclass defaults agree


def test_folder_as_flight(tmp_path, capsys):
    (tmp_path / "run1").mkdir()
    assert_rejected(capsys, tmp_path, [tmp_path / "run1"], "run1: is a folder, not a flight file")


def test_frozen_attitude(tmp_path, capsys):
    """filter=auto crashed (log of zero) on a quaternion that never changes: refused before any work."""
    path = tmp_path / "frozen.csv"
    df = _flight(6000)
    df[["qw", "qx", "qy", "qz"]] = [1.0, 0.0, 0.0, 0.0]
    df.to_csv(path, index=False)
    assert_rejected(capsys, tmp_path, [path], "frozen.csv: every sample has the same attitude", "frozen stream")


def test_frozen_rotor_speeds_refused_by_the_filters(hummingbird):
    """Library callers that skip read_flight: the filters refuse four rotor speeds that never change."""
    from qr.errors import QrInputError
    from qr.estimation import estimate

    df = _flight(3000)
    df[["u1", "u2", "u3", "u4"]] = 5872.0
    with pytest.raises(QrInputError, match="every sample has the same rotor speeds"):
        estimate(df, hummingbird, {"name": "auto", "discretisation": "exact", "tune": {"enabled": True}})
