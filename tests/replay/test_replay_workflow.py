"""The workflow's side of the replay: which flights a set replays and with what, the summary table and the
overview's replay section (the rules themselves run in tests/workflow/)."""

import json

import pandas as pd
import pytest
import yaml

from conftest import ROOT


def data_file():
    return yaml.safe_load((ROOT / "conf" / "data" / "imrclab_crazyflie.yaml").read_text())


def test_the_data_sets_metadata_gives_each_flights_trajectory_and_time_scale():
    """The time scales are the source READMEs' (brushless: data/eckart.md; payload: its README), read through
    qr.flightsets (the sets' ``flown:`` groups, the one record of what each flight flew); the payload's
    sideways flights have no trajectory file and are not replayed."""
    from qr.flightsets import flight_info
    from qr.replay.sets import flight_trajectory, replayed_flights

    d = data_file()
    bl, pl = d["sets"]["brushless"], d["sets"]["payload"]
    assert not any("trajectories" in s for s in d["sets"].values())  # one record: flown:
    assert flight_trajectory(bl, "eckart00") == ("figure8", 1.0) and flight_trajectory(bl, "eckart30") == ("figure8", 0.5)
    assert flight_trajectory(pl, "eckart26") == ("figure8", 0.7) and flight_trajectory(pl, "eckart45") == ("sideways", None)
    assert flight_trajectory(pl, "eckart26") == (flight_info("payload", "eckart26").trajectory,
                                                 flight_info("payload", "eckart26").time_scale)
    own = {"flights": ["a"], "flown": [{"flights": ["a"], "trajectory": "t", "time_scale": 0.8}]}
    assert flight_trajectory(own, "a") == ("t", 0.8) and flight_trajectory({"flights": ["a"]}, "a") is None
    files = d["trajectory_files"]
    assert replayed_flights(bl, files) == bl["flights"][2::3]  # the rollout's held-out flights
    assert all(flight_trajectory(pl, f) for f in replayed_flights(pl, files))
    assert set(replayed_flights(pl, files)) < set(pl["flights"][2::3])  # sideways ones left out


def test_the_replays_overrides_carry_the_sources_facts():
    from qr.replay.sets import overrides_of

    d = data_file()
    o = overrides_of(d["sets"]["payload"], ["eckart08", "eckart13"], d["trajectory_files"])
    assert o[0].startswith("replay.trajectory=") and o[0].endswith("figure8.csv")
    assert o[1] == "replay.timescale=[1.0,0.9]" and "controller.mass=0.0444" in o
    assert "replay.firmware.pwm.d00=0.16660966846998546" in o  # the payload README's d00 (not the brushless one)


def test_the_summary_and_the_overview_show_every_model_with_its_ratio_to_nominal(tmp_path):
    from qr.report.overview import overview_html, replay_table
    from qr.stages.replay_sets import summary_table

    def block(p, a):
        return {"position": {"rmse_m": p, "max_m": 2 * p, "parts_at_s": 0.5}, "attitude": {"rmse_deg": a, "max_deg": 3 * a},
                "rotor_speed": {"rmse_percent": 3.0}, "thrust": {"rmse_N": 0.01}, "diverged_at_s": None}

    d = tmp_path / "brushless"
    d.mkdir()
    (d / "replay.json").write_text(json.dumps({"flights": ["a", "b"], "labels": {"n.yaml": "nominal", "e.yaml": "extended"},
                                               "models": {"n.yaml": block(0.1, 6.0), "e.yaml": block(0.04, 3.0)}}))
    df = summary_table({"brushless": d}, tmp_path / "replay.csv")
    assert list(df["position / nominal"]) == pytest.approx([1.0, 0.4]) and list(df["attitude / nominal"]) == [1.0, 0.5]
    assert (tmp_path / "replay.md").exists()
    shown = replay_table(pd.read_csv(tmp_path / "replay.csv"))
    assert list(shown["position RMSE (m)"]) == ["0.1 (1×)", "0.04 (0.4×)"] and list(shown["flights"]) == [2, 2]
    html = overview_html(pd.DataFrame(), None, {}, [], replay=pd.read_csv(tmp_path / "replay.csv"))
    assert "Closed-loop replay under the vehicle's own controller" in html and "0.04 (0.4×)" in html


def test_a_workflow_without_a_replayed_set_writes_the_tables_header_and_the_overview_reads_it(tmp_path):
    """A data set whose sets name no controller (the custom-data workflow): the summary is the header alone,
    which the overview reads as no replay (it once failed on an empty file)."""
    from qr.stages.replay_sets import SUMMARY_COLUMNS, summary_table

    summary_table({}, tmp_path / "replay.csv")
    df = pd.read_csv(tmp_path / "replay.csv")
    assert list(df.columns) == SUMMARY_COLUMNS and len(df) == 0
