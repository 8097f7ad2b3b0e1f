"""`python -m qr.simulate` and the writers behind the Snakemake rules: tables, figures, MLflow runs."""

import os
import subprocess
import sys

import pandas as pd
import pytest

from conftest import ROOT

SMALL = ["simulate=thesis", "simulate.duration=2.0", "simulate.identification.duration_s=10.0", "simulate.stability.duration_s=0.5",
         "~simulate.sources.drag_wind.estimates.fit_v_q_u"]


def test_writers_make_tables_figures_and_one_run_per_simulation(tmp_path, monkeypatch):
    from qr import tracking
    from qr.sim.simulation import simulate_config
    from qr.stages.simulate import write_study

    monkeypatch.setenv("QR_TRACKING", "on")
    sim = simulate_config(SMALL)
    table = write_study(sim, "tracking", tmp_path / "simulation" / "tracking.csv").table
    stab = write_study(sim, "stability", tmp_path / "simulation" / "stability.csv").table
    csv = pd.read_csv(tmp_path / "simulation" / "tracking.csv")
    assert list(csv["source"].unique()) == ["thesis_model8", "drag_wind"]
    assert len(csv) == len(table) == 4 + 4
    assert (tmp_path / "simulation" / "tracking.md").read_text().startswith("### Closed-loop tracking")
    assert set(pd.read_csv(tmp_path / "simulation" / "stability.csv")["model"]) == {"eq_5_16", "sign_flip",
                                                                                     "fit_v_a_q_u"}
    assert stab.set_index("model").loc["eq_5_16", "lagged_status"] == "diverged"
    for f in ["sim_tracking", "sim_euler", "sim_rmse", "stability_eigenvalues", "stability_divergence"]:
        assert (tmp_path / "figures" / f"{f}.png").stat().st_size > 10_000
    client = tracking._client()
    for stage, n_children in (("simulate", len(csv)), ("stability", 2 * len(stab))):
        runs = client.search_runs([tracking.experiment_id(stage)])
        parents = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
        assert len(parents) == 1 and len(runs) == 1 + n_children
        assert all(r.info.status == "FINISHED" for r in runs)


def _entry(args, tmp_path):
    env = {**os.environ, "QR_TRACKING": "off", "PYTHONPATH": str(ROOT / "src")}
    return subprocess.run([sys.executable, "-m", "qr.simulate", *args, f"results={tmp_path}"], cwd=tmp_path,
                          capture_output=True, text=True, env=env, timeout=300)


def test_hydra_entry_point_runs_and_rejects_bad_config_in_one_line(tmp_path):
    res = _entry(["simulate.task=stability", "simulate.stability.duration_s=0.3", "~simulate.stability.models.fit_v_a_q_u"],
                 tmp_path)
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "simulation" / "stability.csv").exists()
    bad = _entry(["simulate.task=tracking", "simulate.trajectory.yaw=sideways"], tmp_path)
    assert bad.returncode == 2
    err = [line for line in bad.stderr.splitlines() if line.startswith("qr simulate: error")]
    assert len(err) == 1 and "yaw mode" in err[0] and "Traceback" not in bad.stderr
    assert not (tmp_path / "simulation" / "tracking.csv").exists()


@pytest.mark.parametrize("override, match", [("simulate.sources.drag_wind.estimates.fit_v_u.model=magic", "unknown force"),
                                             ("simulate.vehicle=no_such_vehicle", "does not exist; fix: check the path, or name a shipped vehicle \\(asctec_hummingbird"),
                                             ("+simulate.gains.kp=3", "unknown key"),
                                             ("simulate.rate=100", "below 500 Hz"),
                                             ("simulate.sources.learned.enabled=true", "no path given")])
def test_user_mistakes_are_one_clear_error(override, match):
    from qr.errors import QrInputError
    from qr.sim.simulation import simulate_config, tracking_study

    with pytest.raises(QrInputError, match=match):
        tracking_study(simulate_config([*SMALL, override]), progress=False)


def test_crazyflie_config_inherits_the_thesis_study():
    from qr.sim.simulation import simulate_config

    sim = simulate_config(["simulate=crazyflie"])
    assert sim["vehicle"] == "crazyflie21_brushless" and sim["gains"]["q_pos"] == 100.0
    assert sim["sources"]["thesis_model8"]["enabled"] is False and "drag_wind" in sim["sources"]
