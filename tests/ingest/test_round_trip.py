"""Every column of every table qr writes reads back equal to the bit.

A flight stamped in epoch seconds (~1.7e9 s, as ROS and most loggers stamp it) with microsecond or
nanosecond steps, an integer nanosecond stamp carried along, huge and tiny values, NaN dropouts: the
writers (the canonical flight as CSV and Parquet, the report tables' CSV, ``qr summary``'s table, the
learning tables) must give back exactly what they were handed.  The round trip is checked with pandas'
own readers (the file's content) and, for the flight, with ``qr``'s reader (what ``qr diagnose`` sees).
End to end: a synthetic flight shifted to epoch time goes through ``qr ingest`` and ``qr diagnose`` to the
same diagnosis as the unshifted one.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from conftest import VEHICLES, run_cli, small_flight
from qr import datasets
from qr.flight import read_flight, write_flight
from qr.report.tables import write_table

ROUND = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
EPOCH_S = 1.7e9
EPOCH_NS = 1_700_000_000_000_000_000


def assert_bits_equal(a: pd.DataFrame, b: pd.DataFrame) -> None:
    """Same columns, dtypes and values: floats compared by their bits (NaN equal to NaN, -0.0 not 0.0)."""
    assert list(a.columns) == list(b.columns)
    for c in a.columns:
        x, y = a[c].to_numpy(), b[c].to_numpy()
        assert x.dtype == y.dtype, (c, x.dtype, y.dtype)
        if x.dtype.kind == "f":
            np.testing.assert_array_equal(x.view(np.int64), y.view(np.int64), err_msg=c)
        else:
            np.testing.assert_array_equal(x, y, err_msg=c)


# any finite float64, the extremes and subnormals included (hypothesis draws them often)
any_value = st.floats(allow_nan=False, allow_infinity=False, width=64)
value_or_dropout = st.one_of(any_value, st.just(float("nan")))
steps_ns = st.sampled_from([1, 7, 1_000, 2_500, 10_000_000, 3_333_333])  # ns, µs and 100 Hz steps


@st.composite
def flights(draw):
    """A flight in epoch time (t from integer nanoseconds, the ns stamp carried along), any values."""
    n = draw(st.integers(2, 30))
    steps = np.array(draw(st.lists(steps_ns, min_size=n - 1, max_size=n - 1)), np.int64)
    t_ns = EPOCH_NS + draw(st.integers(0, 10**12)) + np.concatenate([[0], np.cumsum(steps)])
    df = pd.DataFrame({"t": t_ns.astype(np.float64) * 1e-9})
    for c in ["px", "py", "pz", "qw", "qx", "qy", "qz", "u1", "u2", "u3", "u4", "ax", "gz", "vbat"]:
        df[c] = draw(st.lists(value_or_dropout, min_size=n, max_size=n))
    df["t_ns"] = t_ns
    return df


@st.composite
def tables(draw):
    """A results table: text, integers, floats of any size with blanks."""
    n = draw(st.integers(1, 12))
    return pd.DataFrame({"flight": [f"f{i}" for i in range(n)],
                         "rows": draw(st.lists(st.integers(-2**63, 2**63 - 1), min_size=n, max_size=n)),
                         "t_start_s": EPOCH_S + np.array(draw(st.lists(st.floats(0, 1e6), min_size=n, max_size=n))),
                         "value": draw(st.lists(value_or_dropout, min_size=n, max_size=n)),
                         "tiny": draw(st.lists(st.floats(-1e-300, 1e-300), min_size=n, max_size=n))})


def _special_flight():
    n = 5
    df = pd.DataFrame({"t": EPOCH_S + np.arange(n) * 1e-6})  # µs steps at epoch time: 4 ULPs apart
    for c, v in {"px": 1e308, "py": -5e-324, "pz": -0.0, "qw": 1 / 3, "qx": np.nan, "qy": 2.0**-1074,
                 "qz": 0.1, "u1": 123456789.123456789, "u2": 1e-7, "u3": np.nextafter(1.0, 2), "u4": 9.999999999e22,
                 "ax": np.pi, "gz": -np.e, "vbat": np.nan}.items():
        df[c] = v
    df["t_ns"] = EPOCH_NS + np.arange(n) * 1000
    return df


@ROUND
@example(_special_flight())
@given(flights())
def test_flight_files_round_trip_to_the_bit(df):
    with tempfile.TemporaryDirectory() as d:
        for name in ("f.csv", "f.parquet"):
            path = Path(d) / name
            write_flight(df, path)
            back = pd.read_parquet(path) if name.endswith(".parquet") else pd.read_csv(path)
            assert_bits_equal(back, df)
            path.unlink()


@st.composite
def stamps(draw):
    """Epoch stamps a logger writes: integer nanoseconds, steps of 0.1 ms to 0.5 s with nanosecond jitter."""
    n = draw(st.integers(2, 40))
    step = draw(st.sampled_from([100_000, 1_000_000, 2_500_000, 10_000_000, 500_000_000]))
    jitter = np.array(draw(st.lists(st.integers(0, step // 10), min_size=n - 1, max_size=n - 1)))
    t_ns = EPOCH_NS + draw(st.integers(0, 10**15)) + np.concatenate([[0], np.cumsum(step + jitter)])
    return t_ns.astype(np.int64)


@ROUND
@example(EPOCH_NS + np.arange(5, dtype=np.int64) * 100_000)
@given(stamps())
def test_qr_reads_back_the_stamps_it_wrote(t_ns):
    """What ``qr diagnose`` reads from a flight ``qr ingest`` wrote: the same stamps, none merged."""
    df = small_flight(len(t_ns), seed=2)
    df["t"] = t_ns.astype(np.float64) * 1e-9
    df["t_ns"] = t_ns
    with tempfile.TemporaryDirectory() as d:
        for name in ("f.csv", "f.parquet"):
            path = Path(d) / name
            write_flight(df, path)
            back = read_flight(path)
            assert_bits_equal(back[["t", "px", "py", "pz", "u1", "t_ns"]], df[["t", "px", "py", "pz", "u1", "t_ns"]])


@ROUND
@given(tables())
def test_result_tables_round_trip_to_the_bit(df):
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "table.csv"
        write_table(df, path, title="a table")
        assert_bits_equal(pd.read_csv(path), df)
        assert path.with_suffix(".md").read_text().startswith("### a table")
        pq = Path(d) / "dataset.parquet"
        datasets.write_table(df, pq)
        assert_bits_equal(pd.read_parquet(pq), df)


def test_qr_summary_writes_its_numbers_whole(tmp_path, capsys):
    """``qr summary`` on an epoch-stamped flight: its CSV holds the numbers flight_summary computed."""
    from qr.ingest.summary import flight_summary
    from qr.vehicle import load_vehicle

    df = small_flight(300, seed=3)
    df["t"] = EPOCH_S + np.arange(len(df)) * 0.01
    f = tmp_path / "a.csv"
    write_flight(df, f)
    v = VEHICLES / "asctec_hummingbird.yaml"
    status, _, err = run_cli(["summary", f, "--vehicle", v, "--out", tmp_path / "s.csv"], capsys)
    assert status == 0, err
    expected = pd.DataFrame([flight_summary(read_flight(f), load_vehicle(v), "a")])
    back = pd.read_csv(tmp_path / "s.csv")
    floats = [c for c in expected if expected[c].dtype.kind == "f"]
    assert floats
    assert_bits_equal(back[floats], expected[floats])


# ---- end to end: epoch stamps through qr ingest and qr diagnose ---------------------------------------

CANDIDATES = "diagnose.candidates=[linear_drag,wind_force,mass_error,thrust_gain]"


def test_an_epoch_stamped_log_is_diagnosed_as_the_same_flight_from_zero(tmp_path, capsys):
    """A synthetic drag flight shifted to t ≈ 1.7e9 s: ``qr ingest`` keeps every stamp (it wrote them at 10 s
    resolution once, and ``qr diagnose`` then refused them as duplicated), and ``qr diagnose`` names the same
    effect with the same parameters.  Not bit-equal: at 1.7e9 s a float64 stamp is a multiple of 2**-22 s
    (0.24 µs), so the shifted log's steps differ from 0.01 s by up to that, a relative 2.4e-5 of a step."""
    from qr.sim.synth import SynthConfig, write_synth
    from qr.vehicle import load_vehicle

    write_synth(tmp_path / "s", load_vehicle(VEHICLES / "asctec_hummingbird.yaml"),
                [{"name": "linear_drag", "parameters": {"kx": 0.3, "ky": 0.3, "kz": 0.1}}],
                SynthConfig(duration=20, seed=1))
    vehicle = tmp_path / "s" / "vehicle.yaml"
    zero = pd.read_csv(tmp_path / "s" / "flight.csv")
    epoch = zero.assign(t=zero["t"] + EPOCH_S)
    epoch.to_csv(tmp_path / "epoch.csv", index=False)
    status, _, err = run_cli(["ingest", tmp_path / "epoch.csv", "--vehicle", vehicle, "--out",
                              tmp_path / "mine.csv"], capsys)
    assert status == 0, err
    mine = read_flight(tmp_path / "mine.csv")
    np.testing.assert_array_equal(mine["t"].to_numpy(), epoch["t"].to_numpy())  # every stamp as given
    docs = []
    for f, out in ((tmp_path / "s" / "flight.csv", "d0"), (tmp_path / "mine.csv", "d1")):
        status, _, err = run_cli(["diagnose", f, "--vehicle", vehicle, "--out", tmp_path / out, CANDIDATES], capsys)
        assert status == 0, err
        docs.append(json.loads((tmp_path / out / "diagnosis.json").read_text()))
    a, b = docs
    assert [e["name"] for e in a["effects"]] == [e["name"] for e in b["effects"]] == ["linear_drag"]
    for ea, eb in zip(a["effects"], b["effects"]):
        for k, x in ea["parameters"].items():
            assert eb["parameters"][k] == pytest.approx(x, rel=1e-4), k
            assert abs(eb["parameters"][k] - x) < 0.01 * ea["stderr"][k], k  # far inside its standard error
    assert a["verdict"] == b["verdict"]
    assert a["split"]["train"][0] + EPOCH_S == pytest.approx(b["split"]["train"][0], abs=1e-6)
