"""Fuzzing the two readers of user files: every input loads or gives one QrInputError line, nothing else.

Hypothesis mutates a valid flight CSV (header names, cells, rows, delimiter, encoding,
compression) and a valid vehicle YAML (any key set to bools, strings, nested lists,
null, huge, NaN or infinite numbers; the text itself cut or re-encoded).  Reproducible
(``derandomize``) and bounded (200 examples per reader, a few seconds).
"""

import functools
import gzip
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from conftest import VEHICLES, small_flight
from qr.errors import QrInputError, QrInputWarning
from qr.flight import read_flight
from qr.vehicle import load_vehicle

HB = VEHICLES / "asctec_hummingbird.yaml"
FUZZ = settings(max_examples=200, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _loads_or_one_line(read, path):
    """``read(path)`` returns, or raises QrInputError whose message is one line; no other warning either."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.simplefilter("ignore", QrInputWarning)  # legal but suspicious input: a warning is the answer
        try:
            return read(path)
        except QrInputError as e:
            msg = str(e)
            assert msg and "\n" not in msg and "; fix: " in msg, msg
            return None


# --- CSV flights ---

def _base_rows(n=40):
    df = small_flight(n, seed=1, yaw_amplitude=0.3)
    return [list(df.columns)] + [[f"{v:.9g}" for v in row] for row in df.to_numpy()]


BASE = _base_rows()
NAMES = BASE[0] + ["ax", "gx", "vbat", "temperature", "", " t", "T", "px.1", "qW", "u5"]
SPECIAL = ["", " ", "nan", "NaN", "inf", "-inf", "1e400", "-1e400", "1e-400", "0", "-0", "true", "null",
           "None", "abc", "1,5", "0x10", "1_000", "١٢", "9" * 400, "\"3\"", "'", "\"", "#", "\\N", "1e", "é"]
cell_text = st.one_of(st.sampled_from(SPECIAL), st.text(max_size=12),
                      st.floats(allow_nan=True, allow_infinity=True).map(repr))

mutation = st.one_of(
    st.tuples(st.just("header"), st.integers(0, 20), st.one_of(st.sampled_from(NAMES), st.text(max_size=6))),
    st.tuples(st.just("drop_column"), st.integers(0, 20), st.none()),
    st.tuples(st.just("cell"), st.tuples(st.integers(1, 60), st.integers(0, 20)), cell_text),
    st.tuples(st.just("drop_row"), st.integers(1, 60), st.none()),
    st.tuples(st.just("copy_row"), st.tuples(st.integers(1, 60), st.integers(1, 60)), st.none()),
    st.tuples(st.just("extra_cell"), st.integers(0, 60), cell_text),
    st.tuples(st.just("truncate_rows"), st.integers(0, 41), st.none()),
)
delimiter = st.sampled_from([","] * 12 + [";", "\t", "|", " ", ", "])  # mostly the right one: the rest then varies
encoding = st.sampled_from(["utf-8"] * 8 + ["utf-8-sig", "latin-1", "utf-16", "cp1252", "gzip", "raw"])
line_end = st.sampled_from(["\n"] * 4 + ["\r\n", "\r"])


def _apply(rows, m):
    kind, where, value = m
    rows = [list(r) for r in rows]
    if kind == "header" and rows:
        rows[0][where % len(rows[0])] = value
    elif kind == "drop_column":
        j = where % len(rows[0])
        rows = [r[:j] + r[j + 1:] for r in rows]
    elif kind == "cell" and len(rows) > 1:
        i, j = where
        r = rows[1 + (i - 1) % (len(rows) - 1)]
        if r:
            r[j % len(r)] = value
    elif kind == "drop_row" and len(rows) > 1:
        del rows[1 + (where - 1) % (len(rows) - 1)]
    elif kind == "copy_row" and len(rows) > 1:
        a, b = ((x - 1) % (len(rows) - 1) + 1 for x in where)
        rows[b] = list(rows[a])
    elif kind == "extra_cell":
        rows[where % len(rows)].append(value)
    elif kind == "truncate_rows":
        rows = rows[:where + 1]
    return rows


@st.composite
def csv_bytes(draw):
    rows = BASE
    for m in draw(st.lists(mutation, max_size=6)):
        rows = _apply(rows, m)
    sep, end = draw(delimiter), draw(line_end)
    text = end.join(sep.join(r) for r in rows) + draw(st.sampled_from([end, ""]))
    enc = draw(encoding)
    if enc == "gzip":
        data = gzip.compress(text.encode("utf-8", "surrogatepass"))
    elif enc == "raw":  # random bytes spliced into the text
        data = bytearray(text.encode("utf-8", "surrogatepass"))
        for pos, b in draw(st.lists(st.tuples(st.integers(0, 10**6), st.binary(min_size=1, max_size=4)),
                                    max_size=3)):
            at = pos % (len(data) + 1)
            data[at:at] = b
        data = bytes(data)
    else:
        data = text.encode(enc, errors="replace")
    return data


@FUZZ
@given(data=csv_bytes())
def test_flight_reader_loads_or_refuses_in_one_line(data, work, hummingbird_vehicle):
    path = work / "flight.csv"
    path.write_bytes(data)
    df = _loads_or_one_line(read_flight, path)
    if df is not None:  # what loads is the canonical flight: the required columns, numbers, increasing t
        assert list(df.columns[:12]) == BASE[0]
        assert (np.diff(df["t"].to_numpy()) > 0).all()
    _loads_or_one_line(lambda p: read_flight(p, hummingbird_vehicle), path)


# --- vehicle YAML ---

yaml_scalar = st.one_of(st.none(), st.booleans(), st.integers(min_value=-10**30, max_value=10**30),
                        st.floats(allow_nan=True, allow_infinity=True),
                        st.sampled_from([1e308, -1e308, 5e-324, 0.0, -0.0, 1, -1, 0.17, 0.7, "plus", "rpm", "rad_s"]),
                        st.text(max_size=10))
yaml_value = st.recursive(yaml_scalar, lambda inner: st.one_of(st.lists(inner, max_size=5),
                                                               st.dictionaries(st.text(max_size=8), inner,
                                                                               max_size=4)),
                          max_leaves=12)
KEYS = ["name", "mass", "inertia", "arm_length", "thrust_coeff", "torque_coeff", "rotor_speed_unit", "layout",
        "rotor_speed_min", "rotor_speed_max", "motor_time_constant", "ground_z", "effects", "extends",
        "description"]
rotor = st.fixed_dictionaries({"x": yaml_value, "y": yaml_value, "yaw_sign": yaml_value})
effect_entry = st.one_of(
    yaml_value,
    st.fixed_dictionaries({"name": st.sampled_from(["linear_drag", "thrust_gain", "cg_offset", "nope"]),
                           "parameters": st.one_of(yaml_value, st.dictionaries(
                               st.sampled_from(["kx", "ky", "kz", "gain", "rx", "ry", "zz"]), yaml_value,
                               max_size=4))}))
vehicle_edit = st.one_of(
    st.tuples(st.sampled_from(KEYS), yaml_value),
    st.tuples(st.just("layout"), st.lists(st.one_of(rotor, yaml_value), min_size=0, max_size=5)),
    st.tuples(st.just("effects"), st.lists(effect_entry, max_size=3)),
    st.tuples(st.just("extends"), st.sampled_from(["vehicle.yaml", "../vehicle.yaml", "missing.yaml", "", "/"])),
    st.tuples(st.sampled_from(KEYS), st.just("<drop>")),
)
HB_RAW = yaml.safe_load(HB.read_text())


@st.composite
def vehicle_bytes(draw):
    raw = dict(HB_RAW)
    for key, value in draw(st.lists(vehicle_edit, max_size=4)):
        if value == "<drop>":
            raw.pop(key, None)
        else:
            raw[key] = value
    text = yaml.safe_dump(raw, sort_keys=False, allow_unicode=True)
    how = draw(st.sampled_from(["plain", "plain", "cut", "splice", "latin-1", "utf-16", "top"]))
    if how == "cut":
        text = text[: draw(st.integers(0, len(text)))]
    elif how == "splice":
        at = draw(st.integers(0, len(text)))
        text = text[:at] + draw(st.sampled_from(["{", "[", ":", "- ", "\t", "&a ", "*a", "!!python/object ", "'"])) \
            + text[at:]
    elif how == "top":  # a document that is not a mapping
        text = yaml.safe_dump(draw(yaml_value))
    return text.encode("utf-8", "surrogatepass") if how not in ("latin-1", "utf-16") \
        else text.encode(how, errors="replace")


@FUZZ
@given(data=vehicle_bytes())
def test_vehicle_reader_loads_or_refuses_in_one_line(data, work):
    path = work / "vehicle.yaml"
    path.write_bytes(data)
    v = _loads_or_one_line(load_vehicle, path)
    if v is not None:  # what loads is physical
        assert v.mass > 0 and np.all(v.inertia > 0) and np.all(np.isfinite(v.rotors.matrix))


@pytest.fixture(scope="module")
def hummingbird_vehicle():
    return load_vehicle(HB)


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


# --- binary logs (PX4 ULog, ROS 1 bag): cut, and a few bytes overwritten ---

damage = dict(cut=st.floats(0.0, 1.0), flips=st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 255)),
                                                     max_size=4))


def _damaged(data: bytes, cut: float, flips) -> bytes:
    data = bytearray(data[:max(int(cut * len(data)), 1)])
    for where, value in flips:
        data[min(int(where * len(data)), len(data) - 1)] = value
    return bytes(data)


PX4_SMALL = VEHICLES.parents[1].parent / "shared" / "data" / "px4-ulog-samples" / "sample_log_small.ulg"


@pytest.mark.skipif(not PX4_SMALL.exists(), reason="PX4 sample logs not present")
@FUZZ
@given(**damage)
@example(cut=1.0, flips=[])  # the intact log
@example(cut=0.8453242092632538, flips=[(0.28898446210299583, 1)])  # a pose stamp jumps ahead and back
# a message cut short: pyulog seeks back before it began and read the same bytes for ever (qr.ingest.ulog._Bounded)
@example(cut=0.1, flips=[(0.43509632595302505, 199)] * 3 + [(0.22260502057659465, 154)])
def test_ulog_reader(tmp_path_factory, cut, flips):
    from qr.ingest import ulog

    path = tmp_path_factory.mktemp("ulog") / "log.ulg"
    path.write_bytes(_damaged(PX4_SMALL.read_bytes(), cut, flips))
    _assert_a_flight_or_nothing(_loads_or_one_line(lambda f: ulog.read(f, check=False), path), intact=cut == 1.0 and not flips)


@FUZZ
@given(**damage)
@example(cut=1.0, flips=[])
def test_rosbag_reader(tmp_path_factory, cut, flips):
    from qr.ingest import rosbag

    path = tmp_path_factory.mktemp("rosbag") / "f.bag"
    path.write_bytes(_damaged(_ros1_bag(), cut, flips))
    _assert_a_flight_or_nothing(_loads_or_one_line(rosbag.read, path), intact=cut == 1.0 and not flips)


def _assert_a_flight_or_nothing(df, intact: bool):
    """What loads is a flight (time strictly increasing, the pose and rotor columns); the intact log loads."""
    if intact:
        assert df is not None
    if df is not None:
        assert {"t", "px", "py", "pz", "qw", "qx", "qy", "qz", "u1", "u2", "u3", "u4"} <= set(df.columns)
        assert len(df) == 0 or bool(np.all(np.diff(df["t"].to_numpy()) > 0))


@functools.lru_cache(maxsize=1)
def _ros1_bag() -> bytes:
    from rosbag_writer import write_bag

    with tempfile.TemporaryDirectory() as d:
        return write_bag(small_flight(60, seed=3), Path(d) / "f.bag", "ros1").read_bytes()
