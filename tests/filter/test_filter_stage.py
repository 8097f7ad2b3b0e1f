"""The filter stage: `python -m qr.filter`, its outputs, MLflow run, errors and reproducibility."""

import json
import os
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT, VEHICLES, run_with_overrides
from qr import states as state_table
from qr.errors import QrInputError
from qr.estimation import estimate
from qr.flight import write_flight
from qr.sim.synth import SynthConfig, synthesize


@pytest.fixture(scope="module")
def flight_csv(tmp_path_factory):
    from qr.vehicle import load_vehicle

    v = load_vehicle(VEHICLES / "asctec_hummingbird.yaml")
    flight, _ = synthesize(v, [], SynthConfig(duration=8.0, rate=100.0, seed=9))
    path = tmp_path_factory.mktemp("flight") / "f1.csv"
    write_flight(flight, path)
    return path


def test_hydra_entry_writes_states_report_and_an_mlflow_run(flight_csv, tmp_path, monkeypatch):
    results = tmp_path / "results"
    env = {**os.environ, "QR_RESULTS": str(results), "QR_TRACKING": "on", "OPENBLAS_NUM_THREADS": "1"}
    out = tmp_path / "states.parquet"
    res = subprocess.run([sys.executable, "-m", "qr.filter", "filter=auto", f"filter.flight={flight_csv}",
                          "filter.vehicle=asctec_hummingbird", f"filter.out={out}"], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    table = pd.read_parquet(out)
    state_table.check(table)
    for c in ["ax", "alx", "u1", "ud1"]:
        assert f"sd_{c}" in table and (table[f"sd_{c}"] > 0).all()
    report = json.loads((tmp_path / "states.nis.json").read_text())
    assert report["filter"] == "auto" and report["smoother"] and set(report["tuning"]) == {"position", "attitude",
                                                                                           "motor"}
    monkeypatch.setenv("QR_RESULTS", str(results))  # read the store the subprocess wrote
    monkeypatch.setenv("QR_TRACKING", "on")
    from qr import tracking

    runs = tracking._client().search_runs([tracking.experiment_id("filter")])
    assert len(runs) == 1
    run = runs[0]
    assert run.info.status == "FINISHED" and run.data.params["filter.name"] == "auto"
    assert run.data.metrics["nis.position.mean"] == pytest.approx(report["nis"]["position"]["mean"])
    arts = {a.path for a in tracking._client().list_artifacts(run.info.run_id)}
    assert arts == {"states.nis.json", "f1_nis.png"}


def test_bad_override_is_one_line_and_status_2(flight_csv, tmp_path):
    env = {**os.environ, "QR_RESULTS": str(tmp_path), "QR_TRACKING": "off"}
    res = subprocess.run([sys.executable, "-m", "qr.filter", f"filter.flight={flight_csv}", "filter.motor.r=-3"],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 2
    assert res.stderr.strip().count("\n") == 0 and "'motor.r' must be a positive number" in res.stderr
    assert not (tmp_path / "filter").exists()


def test_same_input_and_config_give_the_same_bytes(flight_csv, tmp_path):
    for k in ("a", "b"):
        run_with_overrides(flight_csv, VEHICLES / "asctec_hummingbird.yaml", tmp_path / f"{k}.parquet",
                           tmp_path / f"{k}.nis.json", ["filter=auto"])
    assert (tmp_path / "a.nis.json").read_bytes() == (tmp_path / "b.nis.json").read_bytes()
    pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "a.parquet"), pd.read_parquet(tmp_path / "b.parquet"))


def test_quaternion_sign_flips_do_not_reach_the_filter(flight_csv):
    """q and -q are one attitude: flipping the sign of random samples changes no estimate."""
    from qr.flight import read_flight

    flight = read_flight(flight_csv)
    flipped = flight.copy()
    rows = np.random.default_rng(0).random(len(flight)) < 0.3
    flipped.loc[rows, ["qw", "qx", "qy", "qz"]] *= -1
    a, _ = estimate(flight, None, {})
    b, _ = estimate(flipped, None, {})
    pd.testing.assert_frame_equal(a.drop(columns=["nis_q"]), b.drop(columns=["nis_q"]), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("change, message", [
    (lambda f: f.drop(columns=["qz"]), "lacks column"),
    (lambda f: f.assign(u2=np.nan), "u2 are (almost) empty"),
    (lambda f: f.iloc[::-1], "strictly increasing"),
])
def test_unusable_flights_are_one_line_errors(flight_csv, change, message):
    from qr.flight import read_flight

    with pytest.raises(QrInputError, match=message.replace("(", r"\(").replace(")", r"\)")) as e:
        estimate(change(read_flight(flight_csv)), None, {})
    assert "\n" not in str(e.value) and "fix:" in str(e.value)


def test_unknown_config_key_names_the_known_ones(flight_csv):
    from qr.flight import read_flight

    with pytest.raises(QrInputError, match="unknown key 'position.sigma'.*known: q, r"):
        estimate(read_flight(flight_csv), None, {"position": {"sigma": 1}})


def test_thesis_style_figures_nis_figure_and_summary(flight_csv, tmp_path):
    from qr.estimation.plots import FIGURES, nis_figure
    from qr.stages.filter_sets import figures, summarize

    report = run_with_overrides(flight_csv, VEHICLES / "asctec_hummingbird.yaml", tmp_path / "f1.parquet",
                                tmp_path / "f1.nis.json", [])
    paths = figures(flight_csv, tmp_path / "f1.parquet", tmp_path / "fig", title="f1")
    assert sorted(p.name for p in paths) == sorted(f"filter_{k}.png" for k in FIGURES)
    assert all(p.stat().st_size > 10_000 for p in paths)
    nis_figure(pd.read_parquet(tmp_path / "f1.parquet"), report, tmp_path / "nis.png", "f1")
    assert (tmp_path / "nis.png").stat().st_size > 10_000
    summarize({"s/f1": tmp_path / "f1.nis.json"}, tmp_path / "summary.csv")
    table = pd.read_csv(tmp_path / "summary.csv")
    assert list(table["flight"]) == ["s/f1"] and table.loc[0, "position_ok"] == report.nis.position.consistent
    assert (tmp_path / "summary.md").exists()


def test_the_filter_stage_writes_the_estimates_every_diagnosis_reads(tmp_path):
    """The filter stage is the home of the state estimates: its cross-fit file holds each segment's matched
    estimate and even/odd halves; a diagnosis given it reads them instead of filtering again and gets
    the same numbers digit for digit, and so does ``qr diagnose`` on the command line, which filters the
    flight itself (both tune filter=auto on the longest airborne segment, never on ground rows); made
    with other filter settings, the file is not used."""
    from conftest import on_the_ground
    from qr.stages.diagnose import run_diagnosis
    from qr.effects import parse_effect_spec
    from qr.vehicle import load_vehicle

    v = load_vehicle(VEHICLES / "asctec_hummingbird.yaml")
    flight, _ = synthesize(v, [parse_effect_spec("linear_drag:kx=0.3,ky=0.3,kz=0.15")],
                           SynthConfig(duration=40.0, rate=100.0, seed=4))
    t = flight["t"].to_numpy()
    flight = flight[(t < 18.0) | (t > 19.0)].reset_index(drop=True)  # a logger outage: two segments
    flight, _ = on_the_ground(flight, v, before_s=3.0, after_s=2.0, spin_up_s=1.0)  # take-off, landing
    path = tmp_path / "gap.csv"
    write_flight(flight, path)
    vf = VEHICLES / "asctec_hummingbird.yaml"
    xfit = tmp_path / "gap.crossfit.parquet"
    report = run_with_overrides(path, vf, tmp_path / "gap.parquet", tmp_path / "gap.nis.json", ["filter=auto"],
                                track=False, crossfit_out=xfit)
    table = pd.read_parquet(xfit)
    assert sorted(table["segment_start"].unique()) == [3.0, pytest.approx(22.01)]
    assert sorted(table["part"].unique()) == ["even", "full", "odd"]
    assert report.tuned_on_s == (pytest.approx(22.01), pytest.approx(43.0))  # the longer airborne segment

    def diagnose(out, overrides=(), estimates=None, reports=(report,), **kw):
        said = []
        doc = run_diagnosis([path], vf, tmp_path / out, list(overrides), reports=list(reports) or None,
                            estimates=estimates, figures=False, log=said.append, **kw)
        return doc, [m for m in said if m.startswith("estimates of")]

    own, said_own = diagnose("own")
    (read, res), said_read = diagnose("read", estimates=[xfit], return_result=True)
    cli, said_cli = diagnose("cli", reports=())
    assert len(said_read) == 2 and all(m.endswith("read from the filter stage") for m in said_read)
    assert all("filter=auto" in m for m in said_own + said_cli)
    assert json.dumps(own, sort_keys=True) == json.dumps(read, sort_keys=True)
    out_of = {"flights", "out"}  # the command line's doc differs only where it names its own output
    assert json.dumps({k: v for k, v in cli.items() if k not in out_of}, sort_keys=True) == \
        json.dumps({k: v for k, v in read.items() if k not in out_of}, sort_keys=True)
    _, said_other = diagnose("other", ["filter.smoother=false"], estimates=[xfit])
    assert len(said_other) == 2 and not any("read from" in m for m in said_other)
    # the learning data set is labelled from the same estimates: its f_a and tau_a are the diagnosis's
    from qr.stages.learn_sets import build_dataset

    table = build_dataset([xfit], ["gap"], vf, tmp_path / "dataset.parquet")
    prep = res.labels.full
    test = np.flatnonzero(prep.test)
    rows = pd.DataFrame({"t": prep.t[test]}).merge(table.reset_index(), on="t", how="left")
    assert rows["index"].notna().all() and len(test) > 1000
    label = table[[f"{g}.{a}" for g in ("f_a", "tau_a") for a in "xyz"]].to_numpy()[rows["index"].astype(int)]
    np.testing.assert_allclose(label, prep.y[test], rtol=1e-9, atol=1e-12)
    # the rollout of qr evaluate too (its start states: position, velocity, attitude, rate)
    from qr.stages.evaluate import run_evaluation

    said = []
    ev = [run_evaluation([path], [vf], tmp_path / f"ev{k}", ["evaluate.horizon=10"], figures=False,
                         reports=[report], estimates=est, log=said.append)
          for k, est in enumerate((None, [xfit]))]
    assert sum("read from the filter stage" in m for m in said) == 2
    assert json.dumps(ev[0]["models"], sort_keys=True) == json.dumps(ev[1]["models"], sort_keys=True)


def test_the_report_reads_back_into_an_equal_typed_result_that_writes_the_same_bytes(flight_csv, tmp_path):
    """``.nis.json`` as the filter stage writes it (filter=auto: the tuning record too) reads back
    (:func:`qr.intake.read_reports`) into a report equal to the one the run returned, field by field, and
    that one's document is the file again, byte for byte."""
    from qr.atomic import write_json
    from qr.estimation.nis import NisReport
    from qr.intake import read_reports

    nis = tmp_path / "f1.nis.json"
    report = run_with_overrides(flight_csv, VEHICLES / "asctec_hummingbird.yaml", tmp_path / "f1.parquet", nis,
                                ["filter=auto"], track=False)
    (back,) = read_reports([nis])
    assert isinstance(back, NisReport) and back == report
    assert back.flight == "f1" and back.tuning and len(back.tuned_on_s) == 2 and isinstance(back.inconsistent, tuple)
    write_json(tmp_path / "again.json", back.to_json())
    assert (tmp_path / "again.json").read_bytes() == nis.read_bytes()
