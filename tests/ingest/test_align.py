"""Stream alignment (``qr.ingest.align``): a known offset between the motion capture and the gyro of a
synthetic flight is found, to a sample, and undone."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from conftest import VEHICLES, run_cli
from qr.effects import parse_effect_spec
from qr.ingest import align
from qr.sim.synth import SynthConfig, write_synth
from qr.vehicle import load_vehicle

HB = VEHICLES / "asctec_hummingbird.yaml"
SAMPLE = 0.01  # s at 100 Hz


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    d = tmp_path_factory.mktemp("align")
    write_synth(d, load_vehicle(HB), [parse_effect_spec("linear_drag:kx=0.3,ky=0.3,kz=0.15")],
                SynthConfig(duration=60, seed=4))
    fl, truth = pd.read_csv(d / "flight.csv"), pd.read_parquet(d / "truth.parquet")
    rng = np.random.default_rng(4)
    for a in "xyz":  # a gyro: the true body rate with white noise and a bias
        fl[f"g{a}"] = truth[f"w{a}"].to_numpy() + 0.02 * rng.standard_normal(len(fl)) + 0.01
    return fl


def _stamped(fl, by):
    """The gyro stamped ``by`` seconds late: logged(t) = true(t - by)."""
    t, out = fl["t"].to_numpy(), fl.copy()
    for c in ("gx", "gy", "gz"):
        out[c] = np.interp(t - by, t, fl[c].to_numpy(), left=np.nan, right=np.nan)
    return out


@pytest.mark.parametrize("late", [-0.02, 0.0, 0.035, 0.1])
def test_a_known_gyro_offset_is_found_to_a_sample(flight, late):
    found = align.offsets(_stamped(flight, late))["gyro"]
    assert found["offset_s"] == pytest.approx(late, abs=SAMPLE)
    assert found["correlation"] > 0.9


def test_moving_the_gyro_undoes_the_offset(flight):
    off = _stamped(flight, 0.05)
    moved = align.apply(off, align.offsets(off))
    assert abs(align.offsets(moved)["gyro"]["offset_s"]) < SAMPLE
    assert moved["gx"].iloc[-3:].isna().all()  # the rows the moved stream does not reach are dropouts
    assert align.offsets(flight.drop(columns=["gx", "gy", "gz"])) == {}  # no gyro, nothing to align


def test_qr_ingest_reports_the_offset_and_moves_only_when_asked(flight, tmp_path, capsys):
    src = tmp_path / "late.csv"
    _stamped(flight, 0.05).dropna().to_csv(src, index=False)
    status, out, err = run_cli(["ingest", src, "--vehicle", HB, "--out", tmp_path / "a.parquet"], capsys)
    assert status == 0, err
    assert "gyro stamped +" in out and "moved" not in out
    kept = pd.read_parquet(tmp_path / "a.parquet")
    assert kept["gx"].to_numpy() == pytest.approx(pd.read_csv(src)["gx"].to_numpy())
    status, out, err = run_cli(["ingest", src, "--vehicle", HB, "--out", tmp_path / "b.parquet", "--align"], capsys)
    assert status == 0, err
    assert "moved" in out
    moved = pd.read_parquet(tmp_path / "b.parquet")
    assert abs(align.offsets(moved)["gyro"]["offset_s"]) < SAMPLE
