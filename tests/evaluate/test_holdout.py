"""Held-out splits (``evaluate.split``, qr.holdout) and what each flight flies (qr.flightsets).

The property (issue 33): no trajectory or speed split puts the held-out trajectory type or time scale on
both sides; a speed split scores only flights faster than every training flight of their type; the
validation flights (early stopping) are training flights, never scored ones, and under a trajectory or
speed split repeat no training trajectory.  The facts of the data set are checked against the source's
README (brushless_flights/README.md, brushless_flights_payload/README.md, brushed_flights/README.md).
"""

import jsonschema
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from qr.errors import QrInputError
from qr.flightsets import FlightInfo, flight_info, load_sets, parse_flown, spread
from qr.holdout import SplitConfig, assign, folds, named, validation

from conftest import ROOT

DATA = ROOT / "conf" / "data" / "imrclab_crazyflie.yaml"

TYPES = ["figure8", "sideways", "yaw", "circle"]
SCALES = [0.5, 0.6, 0.7, 0.8, 1.0, 2.0]


@st.composite
def flight_sets(draw):
    """A set of flights: each a trajectory type, a time scale or none, and one or more repeats."""
    groups = draw(st.lists(st.tuples(st.sampled_from(TYPES), st.one_of(st.none(), st.sampled_from(SCALES)),
                                     st.integers(1, 4)), min_size=1, max_size=8, unique_by=lambda g: g[:2]))
    infos, k = {}, 0
    for traj, scale, n in groups:
        for _ in range(n):
            infos[f"f{k:02d}"] = FlightInfo(f"f{k:02d}", traj, scale)
            k += 1
    order = draw(st.permutations(list(infos)))
    return list(order), infos


@st.composite
def splits(draw, infos):
    kind = draw(st.sampled_from(["repeat", "trajectory", "speed"]))
    types = sorted({i.trajectory for i in infos.values()})
    scales = sorted({i.time_scale for i in infos.values() if i.time_scale is not None})
    if kind == "repeat":
        return SplitConfig(kind="repeat")
    if kind == "trajectory" and (draw(st.booleans()) or not scales):
        return SplitConfig(kind="trajectory", trajectories=draw(st.lists(st.sampled_from(types), min_size=1,
                                                                          max_size=2, unique=True)))
    if kind == "trajectory":
        return SplitConfig(kind="trajectory", time_scales=draw(st.lists(st.sampled_from(scales), min_size=1,
                                                                         max_size=2, unique=True)))
    given_scales = draw(st.lists(st.sampled_from(scales), max_size=2, unique=True)) if scales else []
    return SplitConfig(kind="speed", time_scales=given_scales)


def assert_split_holds(flights, infos, split):
    try:
        a = assign(flights, split, infos)
    except QrInputError:
        return None  # a split this set cannot make (nothing to train on or to score, not an extrapolation)
    train, test = set(a.train), set(a.test)
    assert train and test and not train & test
    assert train | test | set(a.unused) == set(flights)
    assert [f for f in flights if f in train] == list(a.train)  # the set's order kept
    if split.kind == "trajectory" and split.trajectories:
        assert not {infos[f].trajectory for f in train} & {infos[f].trajectory for f in test}
    if split.kind == "trajectory" and split.time_scales:
        assert not {infos[f].time_scale for f in train} & {infos[f].time_scale for f in test}
    if split.kind == "speed":
        assert all(infos[f].time_scale is not None for f in train | test)
        for f in test:  # faster (a smaller time scale) than every training flight of its type
            same = [infos[g].time_scale for g in train if infos[g].trajectory == infos[f].trajectory]
            assert all(infos[f].time_scale < s for s in same)
        for t in TYPES:
            assert not ({infos[f].time_scale for f in train if infos[f].trajectory == t}
                        & {infos[f].time_scale for f in test if infos[f].trajectory == t})
    fit, val, by = validation(a.train, split, 0.2, infos)
    assert set(fit) | set(val) == train and not set(val) & test and not set(fit) & set(val)
    if len(train) > 1:
        assert val  # early stopping always has flights of its own
    if by == "trajectory":
        assert not {infos[f].trajectory_id() for f in fit} & {infos[f].trajectory_id() for f in val}
    return a


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_no_split_puts_a_held_out_type_or_scale_on_both_sides_and_validation_never_scores(data):
    flights, infos = data.draw(flight_sets())
    split = data.draw(splits(infos))
    assert_split_holds(flights, infos, split)


WORKFLOW_SPLITS = [
    ("brushless", {"kind": "trajectory", "time_scales": [s]}) for s in (1.0, 0.9, 0.8, 0.7, 0.6, 0.5)
] + [("brushless", {"kind": "speed", "time_scales": [0.6, 0.5]}),
     ("payload", {"kind": "trajectory", "trajectories": ["sideways"]}),
     ("payload", {"kind": "trajectory", "trajectories": ["figure8"]})] + [
    ("brushed", {"kind": "trajectory", "trajectories": [t]}) for t in ("figure8", "yaw", "circle")]


@pytest.mark.parametrize("set_name, spec", WORKFLOW_SPLITS)
def test_the_workflows_splits_of_the_measured_sets_hold_the_property(set_name, spec):
    fs = load_sets(DATA)[set_name]
    a = assert_split_holds(list(fs.flights), fs.infos, SplitConfig(**spec))
    assert a is not None


def test_the_speed_split_of_the_brushless_set_trains_on_one_to_point_seven():
    fs = load_sets(DATA)["brushless"]
    a = assign(fs.flights, SplitConfig(kind="speed", time_scales=[0.6, 0.5]), fs.infos)
    assert sorted({fs.infos[f].time_scale for f in a.train}) == [0.7, 0.8, 0.9, 1.0]
    assert sorted({fs.infos[f].time_scale for f in a.test}) == [0.5, 0.6] and len(a.test) == 10
    # the default: the fastest third of the six scales, the same two
    assert assign(fs.flights, SplitConfig(kind="speed"), fs.infos).test == a.test
    # validation: the fastest training time scale, whole (five flights of 0.7)
    _, val, by = validation(a.train, SplitConfig(kind="speed"), 0.2, fs.infos)
    assert by == "trajectory" and {fs.infos[f].time_scale for f in val} == {0.7} and len(val) == 5


def test_a_speed_split_that_is_no_extrapolation_is_refused():
    fs = load_sets(DATA)["brushless"]
    with pytest.raises(QrInputError, match="no extrapolation"):
        assign(fs.flights, SplitConfig(kind="speed", time_scales=[0.9]), fs.infos)


def test_the_repeat_split_is_every_third_flight_and_says_whether_trajectories_repeat():
    fl = [f"f{i}" for i in range(7)]
    a = assign(fl, SplitConfig())
    assert a.test == ("f2", "f5") and a.train == ("f0", "f1", "f3", "f4", "f6")
    assert a.held_out == "every third flight"  # nothing known about the flights: nothing claimed
    cfg = {s: SplitConfig(kind="repeat", data=str(DATA), set=s) for s in ("brushless", "payload", "brushed")}
    sets = load_sets(DATA)
    assert assign(sets["brushless"].flights, cfg["brushless"]).held_out == "every third flight (same trajectories)"
    assert assign(sets["payload"].flights, cfg["payload"]).held_out == "every third flight (same trajectories)"
    # brushed: jana02 (figure-8 ×0.8, controller 2) and jana06 (yaw ×2.0) repeat no training flight exactly
    assert assign(sets["brushed"].flights, cfg["brushed"]).held_out.startswith(
        "every third flight (0 of 2 repeat a training trajectory, 2 of 2")


@pytest.mark.parametrize("spec, needle", [
    ({"kind": "trajectory"}, "neither given"),
    ({"kind": "trajectory", "trajectories": ["a"], "time_scales": [1.0]}, "both given"),
    ({"kind": "repeat", "trajectories": ["a"]}, "not named ones"),
    ({"kind": "speed", "trajectories": ["a"]}, "not trajectories"),
    ({"kind": "speed", "time_scales": [-1]}, "positive"),
    ({"kind": "sideways"}, "not allowed"),
])
def test_bad_splits_are_one_clear_error(spec, needle):
    with pytest.raises(QrInputError, match=needle):
        SplitConfig(**spec)


def test_a_trajectory_the_set_does_not_fly_is_named_in_the_error():
    fs = load_sets(DATA)["payload"]
    with pytest.raises(QrInputError, match="no flight flies 'random'.*figure8, sideways"):
        assign(fs.flights, SplitConfig(kind="trajectory", trajectories=["random"]), fs.infos)


def test_the_folds_of_the_data_set():
    spec = yaml.safe_load(DATA.read_text())["workflow"]["generalization"]["sets"]
    got = {s: [f.name for f in folds(spec[s], load_sets(DATA)[s].flights, str(DATA), s)] for s in spec}
    assert got["brushless"] == [f"trajectory-ts{s}" for s in ("1", "0.9", "0.8", "0.7", "0.6", "0.5")] + \
        ["speed-ts0.6-0.5"]
    assert got["payload"] == ["trajectory-sideways", "trajectory-figure8"]
    assert got["brushed"] == ["trajectory-figure8", "trajectory-yaw", "trajectory-circle"]


# ---- what the flights fly ----

def test_the_data_set_says_what_each_flight_flies_as_the_sources_readmes_do():
    # brushless_flights/README.md: eckart{27, 30, 34, 35, 36} TIMESCALE = 0.5, {06, 07, 08, 09, 11} 0.9
    assert flight_info("brushless", "eckart27", DATA).time_scale == 0.5
    assert flight_info("brushless", "eckart11", DATA).time_scale == 0.9
    assert flight_info("brushless", "eckart00", DATA).trajectory == "figure8"
    # brushless_flights_payload/README.md: eckart{22, 24, 26, 27, 28} TIMESCALE = 0.7; eckart{72..76} sideways
    # along x, TIME = 1.3; eckart{51..56} along y, TIME = 1.3
    assert flight_info("payload", "eckart28", DATA).time_scale == 0.7
    i = flight_info("payload", "eckart74", DATA)
    assert (i.trajectory, i.axis, i.segment_s, i.time_scale, i.payload_g) == ("sideways", "x", 1.3, None, 4.7)
    assert flight_info("payload", "eckart56", DATA).axis == "y"
    # brushed_flights/README.md: jana11 circle0.csv, TIMESCALE 3.0, CONTROLLER 1, HEIGHT 0.5
    i = flight_info("brushed", "jana11", DATA)
    assert (i.trajectory, i.time_scale, i.controller, i.height) == ("circle", 3.0, "1", 0.5)
    assert flight_info("brushed", "jana30", DATA).trajectory == "random"  # described, though not used
    # the default data set is the shipped one; a file named after the flight reads the same
    assert flight_info("brushless", "results/ingest/brushless/eckart27.parquet").time_scale == 0.5


def test_every_used_flight_is_described_once_and_the_schema_accepts_the_file():
    for s in load_sets(DATA).values():
        assert set(s.flights) <= set(s.infos)
    schema = yaml.safe_load((ROOT / "workflow" / "schemas" / "data.schema.yaml").read_text())
    jsonschema.validate(yaml.safe_load(DATA.read_text()), schema)


@pytest.mark.parametrize("groups, needle", [
    ([{"flights": ["a"], "trajectory": "x"}, {"flights": ["a"], "trajectory": "y"}], "described twice"),
    ([{"flights": ["a"], "trajectory": "x", "timescale": 1}], "unknown key 'timescale'"),
    ([{"flights": ["a"], "trajectory": "x", "time_scale": 0}], "positive"),
    ([{"flights": ["b"], "trajectory": "x"}], "a of the set are not described"),
])
def test_a_wrong_description_is_one_clear_error(groups, needle):
    with pytest.raises(QrInputError, match=needle):
        parse_flown(groups, ["a"])


def test_a_reduced_run_keeps_flights_that_differ():
    sets = load_sets(DATA)
    assert spread(sets["brushless"].flights, sets["brushless"].infos, 2) == ["eckart00", "eckart06"]  # 1.0, 0.9
    assert spread(sets["payload"].flights, sets["payload"].infos, 2) == ["eckart06", "eckart43"]  # fig-8, sideways
    assert spread(sets["brushless"].flights, sets["brushless"].infos, 1) == ["eckart00"]
    assert spread(["c", "a", "b"], None, 2) == ["c", "a"]  # not described: the first N


def test_learn_residual_refuses_a_flight_the_split_scores(tmp_path):
    """``qr learn residual`` with a trajectory split: a training flight that flies the held-out trajectory is
    refused before any work (it would score a trained flight)."""
    from qr.stages.learn_residual import run_residual

    from conftest import VEHICLES, small_flight

    data = tmp_path / "d.yaml"
    data.write_text(yaml.safe_dump({"root": ".", "sets": {"s": {"vehicle": "v", "flights": ["a", "b"], "flown": [
        {"flights": ["a"], "trajectory": "figure8"}, {"flights": ["b"], "trajectory": "circle"}]}}}))
    paths = []
    for k, name in enumerate(("a", "b")):
        small_flight(seed=k).to_csv(tmp_path / f"{name}.csv", index=False)
        paths.append(tmp_path / f"{name}.csv")
    over = ["evaluate.split.kind=trajectory", "evaluate.split.trajectories=[circle]", f"evaluate.split.data={data}",
            "evaluate.split.set=s"]
    with pytest.raises(QrInputError, match="evaluate.split scores this flight.*circle"):
        run_residual(paths, VEHICLES / "asctec_hummingbird.yaml", tmp_path / "out", over, track=False,
                     log=lambda m: None)
    assert not (tmp_path / "out" / "training.json").exists()
    assert named(FlightInfo("b", "circle"), SplitConfig(kind="trajectory", trajectories=["circle"]))
    assert not named(FlightInfo("a", "figure8", 1.0), SplitConfig(kind="speed", time_scales=[0.5]))
