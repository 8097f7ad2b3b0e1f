"""Two Hydra sweeps and a Snakemake run write to one tracking store at once: nothing lost, nothing twice.

The workflow (reduced config with one flight per set, target results/filter/summary.csv: MLflow
runs brushless/eckart00, payload/eckart06 and summary in stage qr-filter) runs while two sweeps of
`python -m qr.learn -m` write to the same store (QR_RESULTS): one with the joblib launcher (2
worker processes), one with the basic launcher, 12 jobs each.  That is 3 + 2 x (1 parent + 12
children) = 29 runs, each exactly once.

The overlap is forced, not hoped for (on a busy machine the workflow's runs could end before a sweep
starts): the sweeps open their parent runs first and hold their jobs at a barrier (sweep_barrier);
the workflow starts once both parents are open, and the jobs are released once the workflow's first
run is in the store.  So each sweep's parent run starts before the workflow's runs and ends after
the first of them started, whatever the machine's load.
"""

import subprocess

import pytest

import workflow_runs as wr
from conftest import ROOT
from qr.stages.sweep_callback import PARENT_FILE
from sweep_barrier import barrier_overrides

GRID = ["model=linear", "learn.inputs=[v_b],[v_b,u],[q,u]", "learn.target=f_a,tau_a", "model.alpha=0,1e-6"]  # 12 jobs
JOBS = 12


@pytest.fixture
def dataset(tmp_path):
    from learning_data import random_table

    from qr.datasets import write_table

    path = tmp_path / "dataset.parquet"
    write_table(random_table(flights=4, n=300), path)
    return path


@pytest.mark.slow  # a Snakemake run beside two sweeps (~1 min): started first under xdist (conftest), not last
def test_two_sweeps_and_the_workflow_share_one_store(tmp_path, dataset):
    path = wr.workdir(tmp_path / "wf")
    results = path / "results"
    release = tmp_path / "release"
    barrier = barrier_overrides(release, "job_start")
    env = wr.env(path, PYTHONPATH=wr.with_tests_path())  # the sweeps import sweep_barrier
    sweeps = {}
    for name, launcher in (("A", ["hydra/launcher=joblib2"]), ("B", [])):
        out = tmp_path / name
        sweeps[name] = subprocess.Popen(
            [wr.PYTHON, "-m", "qr.learn", "-m", *GRID, f"learn.dataset={dataset}", f"learn.out={out}",
             f"hydra.sweep.dir={out / 'hydra'}", *launcher, *barrier],
            cwd=ROOT, env=env, stdout=open(tmp_path / f"{name}.log", "w"), stderr=subprocess.STDOUT)
    for name, p in sweeps.items():  # both parent runs open, their jobs held at the barrier
        wr.wait_for(lambda: (tmp_path / name / PARENT_FILE).exists(), p, f"sweep {name} opened its parent run")
    wf = wr.start(path, "--cores", "2", "--configfile", wr.CI_CONFIG, "--config", "flights_per_set=1",
                  "--", "results/filter/summary.csv")
    wr.wait_for(lambda: wr.stored(results, "filter"), wf, "the workflow's first run")
    release.touch()  # the sweeps' 24 jobs now write beside the workflow's remaining runs
    for name, p in sweeps.items():
        assert p.wait(timeout=wr.HANG_GUARD_S) == 0, wr.tail(tmp_path / f"{name}.log")
    assert wf.wait(timeout=wr.HANG_GUARD_S) == 0, wr.tail(path / "snakemake.log")

    runs = list(wr.all_runs(results).values())
    assert len(runs) == 3 + 2 * (1 + JOBS)
    assert all(r.info.status == "FINISHED" for r in runs)
    assert not any("qr.killed" in r.data.tags for r in runs)  # no live writer was taken for a dead one

    by_stage = {}
    for r in runs:
        by_stage.setdefault(r.data.tags["qr.stage"], []).append(r)
    filt = sorted(r.info.run_name for r in by_stage["filter"])
    assert filt == ["brushless/eckart00", "payload/eckart06", "summary"]

    learn = by_stage["learn"]
    parents = {r.info.run_name: r for r in learn if r.data.tags.get("qr.parent") == "true"}
    assert sorted(parents) == ["sweep A", "sweep B"]
    intervals = {}
    for name, parent in parents.items():
        children = [r for r in learn if r.data.tags.get("mlflow.parentRunId") == parent.info.run_id]
        assert sorted(r.info.run_name for r in children) == [f"job{i:03d}" for i in range(JOBS)]
        assert parent.data.metrics["runs"] == JOBS
        assert len((tmp_path / name.split()[-1] / "runs.csv").read_text().splitlines()) == 1 + JOBS
        intervals[name] = (parent.info.start_time, parent.info.end_time)
    # they did write at the same time (forced above): each sweep overlaps the workflow's filter runs
    wf_start = min(r.info.start_time for r in by_stage["filter"])
    wf_end = max(r.info.end_time for r in by_stage["filter"])
    for name, (s, e) in intervals.items():
        assert s < wf_end and e > wf_start, f"sweep {name} did not overlap the workflow"
