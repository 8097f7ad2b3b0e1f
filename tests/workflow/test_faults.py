"""Killing the workflow mid-run (Ctrl-C, then SIGKILL) and rerunning the plain command completes it.

One run of the reduced workflow (conf/workflow_ci.yaml) is interrupted twice -- Ctrl-C, then
SIGKILL, each time while a learning sweep has its MLflow parent run open -- and resumed each time
with `snakemake --cores 2` (after the SIGKILL, `snakemake --unlock` first: Snakemake's lock is
Snakemake's) (tests/workflow/workflow_runs.py: faulted_run).  Checked: no output is ever
half-written, the killed jobs' runs end FAILED or KILLED, no run is lost, the store stays readable,
and the rerun needs no other clean-up (no --rerun-incomplete, no deleting files).  tests/workflow/test_determinism.py
checks that its tables equal those of an uninterrupted run.
"""

import pytest

import workflow_runs as wr

DONE = {"FINISHED", "FAILED", "KILLED"}


@pytest.fixture(scope="session")
def faulted(tmp_path_factory):
    return wr.faulted_run(tmp_path_factory)


def _status(runs):
    return {rid: r.info.status for rid, r in runs.items()}


def test_ctrl_c_ends_every_run_and_leaves_no_half_written_output(faulted):
    assert faulted["sigint_rc"] != 0  # the workflow stopped
    runs = faulted["after_sigint"]
    # every process got SIGINT and closed its run: nothing is left RUNNING, and the runs that were
    # open when Ctrl-C came (the sweep's parent among them) ended FAILED or KILLED
    left = {r.info.run_name: r.data.tags for r in runs.values() if r.info.status not in DONE}
    assert not left, f"runs left open: {left}"
    open_parents = faulted["sigint_parents"] & faulted["sigint_open"]
    # (a sweep may finish in the moment between the look at the store and Ctrl-C: FINISHED before it)
    cut = {rid for rid in open_parents if runs[rid].info.end_time >= faulted["sigint_ms"]}
    assert cut, "no sweep was open when Ctrl-C came"
    for rid in open_parents:
        info = runs[rid].info
        assert info.status in ("FAILED", "KILLED") if rid in cut else info.status == "FINISHED", info
    assert faulted["after_sigint_broken"] == []
    assert faulted["locks_after_sigint"] == []  # Snakemake released its lock itself


def test_sigkill_leaves_stale_state_that_the_rerun_clears(faulted):
    runs = faulted["after_sigkill"]
    # SIGKILL runs no clean-up: the open sweep's parent is left RUNNING, the directory stays locked and
    # the killed jobs' outputs marked incomplete -- and still no output is half-written (write-then-rename)
    stale = {rid for rid, r in runs.items() if r.info.status == "RUNNING"}
    assert set(faulted["sigkill_parents"]) <= stale
    assert faulted["locks_after_sigkill"], "the killed run's lock should still be there"
    assert faulted["incomplete_after_sigkill"], "the killed jobs' outputs should be marked incomplete"
    assert faulted["after_sigkill_broken"] == []
    # the plain command refuses the locked directory until `snakemake --unlock`, then completes
    # (without --rerun-incomplete: profiles/default)
    assert faulted["locked_rc"] != 0 and "cannot be locked" in faulted["locked_log"], faulted["locked_log"]
    assert faulted["resume_rc"] == 0, faulted["resume_log"]
    final = faulted["final"]
    for rid in stale:  # marked KILLED by the rerun, saying which process was gone
        assert final[rid].info.status == "KILLED"
        assert f"process {runs[rid].data.tags['qr.pid']} on" in final[rid].data.tags["qr.killed"]


def test_rerun_is_complete_and_nothing_is_lost(faulted):
    results, final = faulted["results"], faulted["final"]
    # nothing left to do: every output exists, is whole and up to date
    rc = wr.snakemake(faulted["path"], *faulted["args"], "--dry-run", log="dryrun.log")
    assert rc == 0 and "Nothing to be done" in (faulted["path"] / "dryrun.log").read_text()
    assert wr.broken_outputs(results) == []
    assert wr.temporaries(results) == []  # orphaned write-then-rename temporaries were removed
    # the store is readable and lost no run: every run seen after each kill is still there
    assert wr.integrity(results) == "ok"
    for before in (faulted["after_sigint"], faulted["after_sigkill"]):
        assert set(before) <= set(final)
    assert {r.info.status for r in final.values()} <= DONE  # no run left RUNNING
    # the earlier runs kept their end state (FINISHED stays FINISHED, KILLED stays KILLED)
    for rid, status in _status(faulted["after_sigint"]).items():
        assert final[rid].info.status == status


def test_each_final_sweep_has_its_jobs_once(faulted):
    """The sweeps that produced the final tables: one FINISHED parent each, its jobs FINISHED once."""
    import pandas as pd

    final = faulted["final"]
    for sweep_dir in sorted((faulted["results"] / "learn").glob("*/runs.csv")):
        runs_csv = pd.read_csv(sweep_dir)
        parent_id = (sweep_dir.parent / ".mlflow_parent").read_text().strip()
        parent = final[parent_id]
        assert parent.info.status == "FINISHED"
        children = [r for r in final.values() if r.data.tags.get("mlflow.parentRunId") == parent_id]
        names = sorted(r.info.run_name for r in children)
        assert names == sorted(runs_csv["name"])  # no job lost, none twice
        assert all(r.info.status == "FINISHED" for r in children)
        assert parent.data.metrics["runs"] == len(runs_csv)


# ---- the pieces, one process at a time ---------------------------------------------------------

import os  # noqa: E402
import signal  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import textwrap  # noqa: E402

# the whole-workflow runs are shared (memoised) between these modules: keep them on one xdist worker
pytestmark = pytest.mark.xdist_group("reduced_workflow")

OPEN_RUN = textwrap.dedent("""
    import sys, time
    from qr import tracking

    class Slow:  # a finalizer that is running when the signal comes (Python drops exceptions there)
        def __del__(self):
            print("in-finalizer", flush=True)
            time.sleep(300)  # until the signal: it lands here however long the test takes to send it

    with tracking.run("unit", sys.argv[1], {"a": 1}) as r:
        print("open", r.id, flush=True)
        if sys.argv[2] == "finalizer":
            x = Slow()
            del x
        time.sleep(300)
""")


@pytest.fixture(scope="module")
def _store(tmp_path_factory):
    return tmp_path_factory.mktemp("unit_store")


@pytest.fixture
def tracked(_store, monkeypatch):
    """Tracking on, into one store for this module's unit tests (creating a store costs seconds)."""
    monkeypatch.setenv("QR_TRACKING", "on")
    monkeypatch.setenv("QR_RESULTS", str(_store))


def _open_run(name, mode="plain"):
    """A process with an open run; returns (process, run id) once the run is open."""
    p = subprocess.Popen([sys.executable, "-c", OPEN_RUN, name, mode], stdout=subprocess.PIPE, text=True,
                         env={**os.environ, "QR_TRACKING": "on"})
    line = p.stdout.readline().split()
    assert line[:1] == ["open"], line
    return p, line[1]


def _runs():
    from qr import tracking

    c = tracking._client()
    return {r.info.run_id: r for r in c.search_runs([tracking.experiment_id("unit")], max_results=1000)}


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_sigterm_and_sigint_end_an_open_run_killed(sig, tracked):
    p, rid = _open_run("signalled")
    p.send_signal(sig)
    assert p.wait(timeout=120) != 0
    assert _runs()[rid].info.status == "KILLED"


def test_a_signal_during_a_finalizer_is_not_lost(tracked):
    """SIGTERM arriving while a finalizer runs: Python drops the exception raised there; the run
    must still end KILLED and the process stop (not sleep on as if nothing happened)."""
    p, rid = _open_run("finalizer", "finalizer")
    assert p.stdout.readline().strip() == "in-finalizer"
    p.send_signal(signal.SIGTERM)
    assert p.wait(timeout=120) != 0  # it would sleep 300 s if the signal were lost
    assert _runs()[rid].info.status == "KILLED"


def test_sigkilled_run_is_marked_killed_by_the_next_run_and_a_live_one_is_not(tracked):
    from qr import procs, tracking

    tracking._reaped = False  # this process may have looked for stale runs already

    dead, dead_id = _open_run("sigkilled")
    live, live_id = _open_run("alive")
    dead.kill()
    dead.wait()
    assert _runs()[dead_id].info.status == "RUNNING"  # SIGKILL: nothing could close it
    with tracking.run("unit", "next", {}):  # the first run of a process looks for stale ones
        pass
    runs = _runs()
    assert runs[dead_id].info.status == "KILLED"
    assert f"process {dead.pid} on {procs.host()}" in runs[dead_id].data.tags["qr.killed"]
    assert runs[live_id].info.status == "RUNNING" and "qr.killed" not in runs[live_id].data.tags
    assert tracking.reap_stale() == []  # nothing else to mark
    live.send_signal(signal.SIGTERM)
    live.wait(timeout=120)
    assert _runs()[live_id].info.status == "KILLED"


def _dead_pid():
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_orphaned_temporaries_are_removed_and_live_ones_kept(tmp_path):
    from qr import procs
    from qr.atomic import atomic_path

    me = procs.identity()
    dead = procs.identity(_dead_pid())
    orphan = tmp_path / f".table.csv.{procs.TEMP_TAG}-{dead['host']}-{dead['pid']}-{dead['start']}.abcd1234.csv"
    orphan_dir = tmp_path / f".best.{procs.TEMP_TAG}-{dead['host']}-{dead['pid']}-{dead['start']}.abcd1234"
    other_host = tmp_path / f".table.csv.{procs.TEMP_TAG}-elsewhere-{dead['pid']}-1.abcd1234.csv"
    orphan.write_text("half")
    orphan_dir.mkdir()
    other_host.write_text("half")
    with atomic_path(tmp_path / "out.csv") as live:  # this process's own temporary, being written
        assert f"{procs.TEMP_TAG}-{me['host']}-{me['pid']}-" in live.name
        live.write_text("x")
        removed = procs.remove_orphan_temporaries(tmp_path)
        assert live.exists()
    assert sorted(removed) == sorted([orphan, orphan_dir])
    assert not orphan.exists() and not orphan_dir.exists() and other_host.exists()
    assert (tmp_path / "out.csv").read_text() == "x"
