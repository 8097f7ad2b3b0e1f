"""The whole (reduced) workflow on a data set that is not the Crazyflie one: `--config data=my_data.yaml`.

Two sets of `qr synth` Hummingbird flights with a hidden drag, one written as canonical CSVs and one as
ROS 2 bags (sqlite3 folders), a vehicle given by name, no chain (no set is carried over to another):
every rule of `rule all` runs, and each set's diagnosis names the hidden drag.
"""

from __future__ import annotations

import json

import pandas as pd
import pytest
import yaml

from conftest import VEHICLES
from rosbag_writer import write_bag
from workflow_runs import CI_CONFIG, snakemake, workdir

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("custom_workflow")]


@pytest.fixture(scope="module")
def custom_run(tmp_path_factory):
    from qr.effects import parse_effect_spec
    from qr.sim.synth import SynthConfig, write_synth
    from qr.vehicle import load_vehicle

    tmp = tmp_path_factory.mktemp("custom")
    data = tmp / "data"
    (data / "csv").mkdir(parents=True)
    (data / "bags").mkdir()
    vehicle = load_vehicle(VEHICLES / "asctec_hummingbird.yaml")
    for i in range(2):
        out = tmp / f"synth{i}"
        write_synth(out, vehicle, [parse_effect_spec("linear_drag:kx=0.3,ky=0.3,kz=0.15")],
                    SynthConfig(duration=24.0, rate=100.0, seed=10 + i))  # 2 x 24 s: the drag to 1 %
        flight = pd.read_csv(out / "flight.csv")
        flight.to_csv(data / "csv" / f"f{i}.csv", index=False)
        write_bag(flight, data / "bags" / f"f{i}", "sqlite3", rpm_to_rad_s=2 * 3.141592653589793 / 60)
    spec = {"name": "synthetic", "root": str(data), "format": "auto",
            "sets": {"csv_flights": {"dir": "csv", "suffix": ".csv", "vehicle": "asctec_hummingbird",
                                     "flights": ["f0", "f1"]},
                     "bag_flights": {"dir": "bags", "vehicle": "asctec_hummingbird", "flights": ["f0", "f1"]}}}
    (tmp / "my_data.yaml").write_text(yaml.safe_dump(spec, sort_keys=False))
    run = workdir(tmp / "run")
    # without MLflow, as the determinism test's clean run: this test is about another data set, and tracking (every
    # job importing MLflow, its store) is tested by the fault and concurrency tests
    snakemake(run, "--cores", "2", "--configfile", CI_CONFIG, "--config", f"data={tmp / 'my_data.yaml'}",
              QR_TRACKING="off")
    return run / "results"


def test_every_rule_runs_on_a_data_set_of_csvs_and_ros2_bags(custom_run):
    for s in ("csv_flights", "bag_flights"):
        doc = json.loads((custom_run / "diagnosis" / s / "all" / "diagnosis.json").read_text())
        drag = next(e for e in doc["effects"] if e["name"] == "linear_drag")
        assert drag["parameters"]["kx"] == pytest.approx(0.3, rel=0.15)
    summary = (custom_run / "tables" / "diagnosis_summary.md").read_text()
    assert "csv_flights" in summary and "bag_flights" in summary
    assert (custom_run / "overview.html").exists()
    assert (custom_run / "simulation" / "tracking.csv").exists()
