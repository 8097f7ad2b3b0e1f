"""Beyond one machine: the cluster code paths, run locally.

- profiles/local-cluster: Snakemake's generic-cluster executor, whose submit / status / cancel
  commands are local stand-ins (workflow/cluster/local_*.sh): every job is submitted as a job
  script, polled, and on Ctrl-C cancelled (SIGTERM to the job, whose MLflow run then ends KILLED).
- profiles/slurm and conf/hydra/launcher/slurm.yaml: resolve (no SLURM here to submit to).
- Hydra's submitit launcher (the SLURM launcher's local twin): a sweep's jobs in separate
  submitit processes, children of one MLflow parent run.
"""

import signal
import subprocess

import pandas as pd
import pytest

import workflow_runs as wr
from conftest import ROOT

PROFILE = ("--profile", "profiles/local-cluster", "--configfile", wr.CI_CONFIG)


def _jobs(path):
    root = path / ".snakemake" / "local-cluster"
    return sorted(root.glob("job.*")) if root.exists() else []  # ids sort by submission time


def _status(path, job):
    return subprocess.run([str(path / "workflow" / "cluster" / "local_status.sh"), job.name], cwd=path,
                          capture_output=True, text=True, check=True).stdout.strip()


@pytest.mark.slow  # a minute of Snakemake and cluster stand-ins: started first under xdist (conftest), not last
def test_cluster_jobs_submit_cancel_and_resume(tmp_path):
    """A small target (results/simulation/stability.csv: one job, MLflow runs open all along) through
    profiles/local-cluster: Ctrl-C while its run is open cancels the job (the cancel command), the
    run ends KILLED; the same command then runs it to the end.  The job is surely running when Ctrl-C
    comes: once its parent run is open, the test holds the store's lock, and the job, opening its next
    (child) run, waits for it."""
    path = wr.workdir(tmp_path / "wf")
    results = path / "results"
    target = ("--", "results/simulation/stability.csv")

    p = wr.start(path, *PROFILE, *target)
    wr.wait_for(lambda: wr.running(results, "stability"), p, "the job opened its MLflow run")
    with wr.store_held(results) as lock:
        wr.wait_for(lambda: wr.waiting_for(lock), p, "the job waiting to open its next run")
        open_runs = wr.running(results, "stability")
        assert wr.kill_group(p, signal.SIGINT) != 0  # Snakemake calls local_cancel.sh for its jobs
        (job,) = _jobs(path)
        wr.wait_for(lambda: (job / "exitcode").exists(), None, "the cancelled job ended")
    assert '"rule": "stability"' in (job / "jobscript.sh").read_text()  # the job script Snakemake wrote
    assert (job / "exitcode").read_text().strip() != "0" and _status(path, job) == "failed"
    runs = wr.all_runs(results)
    open_parents = [rid for rid in open_runs if "mlflow.parentRunId" not in runs[rid].data.tags]
    assert open_parents and {runs[rid].info.status for rid in open_parents} == {"KILLED"}  # SIGTERM reached it
    assert "RUNNING" not in {r.info.status for r in runs.values()}
    assert not (results / "simulation" / "stability.csv").exists()

    wr.snakemake(path, *PROFILE, *target)
    first, second = _jobs(path)
    assert first == job and (second / "exitcode").read_text().strip() == "0" and _status(path, second) == "success"
    assert (path / "snakemake.log").read_text().count("with external jobid") == 2
    table = pd.read_csv(results / "simulation" / "stability.csv")
    assert len(table) > 0
    runs = wr.all_runs(results)
    parents = [r for r in runs.values()
               if r.data.tags["qr.stage"] == "stability" and "mlflow.parentRunId" not in r.data.tags]
    assert sorted(r.info.status for r in parents) == ["FINISHED", "KILLED"]
    # the job's runs were written by the job's own process, not by the Snakemake that submitted it
    (done,) = [r for r in parents if r.info.status == "FINISHED"]
    assert int(done.data.tags["qr.pid"]) not in (p.pid, 0)


def test_slurm_profile_and_launcher_resolve(tmp_path):
    path = wr.workdir(tmp_path / "wf")
    rc = wr.snakemake(path, "--profile", "profiles/slurm", "--configfile", wr.CI_CONFIG, "--dry-run",
                      "--forceall")
    log = (path / "snakemake.log").read_text()
    assert rc == 0
    assert "cpus_per_task=8" in log and "runtime=120" in log  # the learn_sweep jobs' SLURM resources
    from hydra import compose, initialize_config_dir

    from qr.config import register_schemas

    register_schemas()  # as every qr entry point does before composing
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=["hydra/launcher=slurm", "hydra.launcher.partition=p1"],
                      return_hydra_config=True)
    launcher = cfg.hydra.launcher
    assert launcher._target_.endswith("SlurmLauncher")
    assert launcher.partition == "p1" and launcher.timeout_min > 0 and launcher.array_parallelism > 0


@pytest.mark.slow  # not needed to prove an item of issue 7: the SLURM launcher's local twin
def test_submitit_sweep_tracks_one_parent_with_its_jobs(tmp_path):
    from learning_data import random_table

    from qr.datasets import write_table

    dataset = tmp_path / "dataset.parquet"
    write_table(random_table(flights=3, n=200), dataset)
    out = tmp_path / "sweep"
    res = subprocess.run(
        [wr.PYTHON, "-m", "qr.learn", "-m", "model=linear", "learn.inputs=[v_b],[v_b,u]", f"learn.dataset={dataset}",
         f"learn.out={out}", f"hydra.sweep.dir={out / 'hydra'}", "hydra/launcher=submitit_local",
         "hydra.launcher.timeout_min=10"],
        cwd=ROOT, env=wr.env(tmp_path), capture_output=True, text=True, timeout=wr.HANG_GUARD_S)
    assert res.returncode == 0, res.stderr[-3000:]
    runs = list(wr.all_runs(tmp_path / "results").values())
    (parent,) = [r for r in runs if r.data.tags.get("qr.parent") == "true"]
    children = [r for r in runs if r.data.tags.get("mlflow.parentRunId") == parent.info.run_id]
    assert sorted(r.info.run_name for r in children) == ["job000", "job001"]
    assert {r.info.status for r in runs} == {"FINISHED"}
    # each job ran in a submitit process of its own, not in the sweep's
    assert len({r.data.tags["qr.pid"] for r in children} | {parent.data.tags["qr.pid"]}) == 3
    assert len(pd.read_csv(out / "runs.csv")) == 2
