import json
import subprocess
import sys
import textwrap
import time

import pytest

from conftest import ROOT


def test_run_has_provenance_and_status(tmp_path, monkeypatch):
    monkeypatch.setenv("QR_TRACKING", "on")
    from qr import tracking

    data = tmp_path / "d.csv"
    data.write_text("t\n0\n")
    with tracking.run("unit", "ok", {"model": {"layers": 2}}, inputs=[data]) as r:
        r.metrics({"rmse": 0.5})
    with pytest.raises(RuntimeError):
        with tracking.run("unit", "bad", {}):
            raise RuntimeError("boom")
    # a SIGTERM that lands while a compiled (numba) function runs comes back as a SystemError carrying
    # the interrupt ("returned a result with an exception set"): still a killed run, not a failed one
    from qr.procs import Terminated

    with pytest.raises(SystemError):
        with tracking.run("unit", "cut", {}):
            try:
                raise Terminated("terminated by signal 15")
            except Terminated as stop:
                raise SystemError("CPUDispatcher(...) returned a result with an exception set") from stop
    with pytest.raises(SystemError):
        with tracking.run("unit", "crashed", {}):
            raise SystemError("a plain one")
    client = tracking._client()
    runs = {r.info.run_name: r for r in client.search_runs([tracking.experiment_id("unit")])}
    ok = runs["ok"]
    assert ok.info.status == "FINISHED" and runs["bad"].info.status == "FAILED"
    assert runs["cut"].info.status == "KILLED" and runs["crashed"].info.status == "FAILED"
    assert ok.data.params["model.layers"] == "2" and ok.data.metrics["rmse"] == 0.5
    assert ok.data.tags["qr.data_digest"] == tracking.data_digest([data]) != "none"
    assert len(ok.data.tags["mlflow.source.git.commit"]) >= 7
    assert ok.data.tags["qr.config_hash"] == tracking.config_hash({"model": {"layers": 2}})
    assert str(tmp_path) in tracking.tracking_uri()
    # each stage's experiment says what it holds (the UI's description), opens in MLflow 3's model-training
    # view (not its GenAI one) and links a view of its runs table that leads with the stage's metrics
    eid = tracking.experiment_id("diagnose")
    exp = client.get_experiment(eid)
    assert exp.tags[tracking.NOTE].startswith(f"[Runs with their results](?view=results#/experiments/"
                                              f"{eid}/runs?workflowType=machine_learning&viewStateShareKey=results)")
    assert exp.tags[tracking.NOTE].endswith(tracking.DESCRIPTIONS["diagnose"])
    assert exp.tags["mlflow.experimentKind"] == "custom_model_development"
    view = json.loads(exp.tags["mlflow.sharedViewState.results"])
    assert view["selectedColumns"][:2] == ["metrics.`effects_named`", "metrics.`nominal_loss`"] == view["columnOrder"][:2]
    # a run's description: its page shows it first
    with tracking.run("unit", "described", {}, description="Named linear_drag.") as r:
        r.metrics({"rmse": 0.1})
    described = client.get_run(r.id)
    assert described.data.tags[tracking.NOTE] == "Named linear_drag." and described.info.status == "FINISHED"


def test_two_processes_logging_at_once_lose_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv("QR_TRACKING", "on")
    script = textwrap.dedent("""
        import sys
        from qr import tracking
        tag = sys.argv[1]
        for i in range(8):
            with tracking.run("concurrency", f"{tag}-{i}", {"i": i, "tag": tag}) as r:
                r.metrics({"value": i, "a": 1.0, "b": 2.0})
    """)
    procs = [subprocess.Popen([sys.executable, "-c", script, tag], cwd=ROOT) for tag in ("A", "B")]
    assert all(p.wait(timeout=300) == 0 for p in procs)
    from qr import tracking

    runs = tracking._client().search_runs([tracking.experiment_id("concurrency")], max_results=1000)
    names = sorted(r.info.run_name for r in runs)
    assert names == sorted(f"{t}-{i}" for t in "AB" for i in range(8))  # none lost, none duplicated
    assert all(r.info.status == "FINISHED" and r.data.metrics["value"] == float(r.data.params["i"]) for r in runs)


def test_a_cancel_that_lands_while_the_run_is_created_ends_it_killed(tmp_path, monkeypatch):
    """SIGTERM inside MLflow's create_run (a cluster cancel right as the job opens its run): the signal
    waits until the run exists, then stops the job, and the run ends KILLED, not RUNNING for ever."""
    import os
    import signal

    monkeypatch.setenv("QR_TRACKING", "on")
    from qr import tracking
    from qr.procs import Terminated

    client = tracking._client()
    real = type(client).create_run

    def cancelled_meanwhile(self, *args, **kwargs):
        made = real(self, *args, **kwargs)  # the run is in the store ...
        os.kill(os.getpid(), signal.SIGTERM)  # ... and the cancel arrives before create_run returns
        return made

    monkeypatch.setattr(type(client), "create_run", cancelled_meanwhile)
    reached = []
    with pytest.raises(Terminated):
        with tracking.run("unit", "cancelled", {}):
            reached.append(True)
    assert not reached  # the job stopped before its body ran
    runs = {r.info.run_name: r for r in client.search_runs([tracking.experiment_id("unit")])}
    assert runs["cancelled"].info.status == "KILLED"


def test_a_ctrl_c_that_another_thread_takes_waits_until_the_runs_status_is_written(tmp_path, monkeypatch):
    """Ctrl-C while the run's final status is written, taken by another thread of the process (numba's, torch's,
    a timer's: the main thread's signal mask does not hold it there): the status is still written, and the
    interrupt comes right after.  It was lost before, and the run stayed RUNNING until the next job reaped it."""
    import signal
    import threading

    monkeypatch.setenv("QR_TRACKING", "on")
    from qr import tracking

    client = tracking._client()
    real = type(client).set_terminated
    go, taken = threading.Event(), threading.Event()

    def other_thread():  # started before the run, as a pool's threads are: its signal mask is the process's
        go.wait()
        signal.raise_signal(signal.SIGINT)  # this thread's C handler notes it; Python runs the handler in main
        taken.set()

    def interrupted_meanwhile(self, *args, **kwargs):
        go.set()
        assert taken.wait(60)
        sum(range(1000))  # bytecodes: where Python runs the noted handler
        return real(self, *args, **kwargs)

    helper = threading.Thread(target=other_thread, daemon=True)
    helper.start()
    monkeypatch.setattr(type(client), "set_terminated", interrupted_meanwhile)
    with pytest.raises(KeyboardInterrupt):
        with tracking.run("unit", "interrupted at the end", {}):
            pass
    helper.join(60)
    runs = {r.info.run_name: r for r in client.search_runs([tracking.experiment_id("unit")])}
    assert runs["interrupted at the end"].info.status == "FINISHED"


def test_a_ctrl_c_while_a_sweep_opens_its_parent_run_ends_that_run_killed(tmp_path, monkeypatch):
    """Ctrl-C while a sweep writes its parent run's id for the jobs (qr.atomic.write_text raises a signal it held
    during the move when the move is done): the parent run ends KILLED there and then.  It was entered by
    hand, and the close at exit was not yet arranged: the run stayed RUNNING (a CI run of
    tests/workflow/test_faults.py, its Ctrl-C sent as a second sweep started)."""
    monkeypatch.setenv("QR_TRACKING", "on")
    from qr import atomic, tracking
    from qr.stages.sweep_callback import PARENT_FILE, SweepCallback

    real = atomic.write_text

    def interrupted_as_it_ends(path, text):
        real(path, text)
        raise KeyboardInterrupt  # the held Ctrl-C, raised as write_text leaves its held block

    monkeypatch.setattr(atomic, "write_text", interrupted_as_it_ends)
    sweep = SweepCallback()
    with pytest.raises(KeyboardInterrupt):
        sweep._open(tmp_path, "interrupted sweep", {"sweep": "s"})
    run_id = (tmp_path / PARENT_FILE).read_text().strip()
    assert tracking._client().get_run(run_id).info.status == "KILLED"
    sweep._close(RuntimeError("a job of the sweep failed"))  # what the exit hook would do: nothing left to close
    assert tracking._client().get_run(run_id).info.status == "KILLED"


def test_a_sweep_that_never_reaches_its_end_hook_closes_its_parent_run_at_exit(tmp_path, monkeypatch):
    """A sweep interrupted (Ctrl-C while a job runs or at the end) or with a failed job never gets Hydra's end
    hook: its parent run is closed as the process exits, not left RUNNING."""
    monkeypatch.setenv("QR_TRACKING", "on")
    script = textwrap.dedent("""
        import sys
        from pathlib import Path
        from qr.stages.sweep_callback import SweepCallback
        SweepCallback()._open(Path(sys.argv[1]), "sweep", {"sweep": "s"})
        raise KeyboardInterrupt
    """)
    p = subprocess.run([sys.executable, "-c", script, str(tmp_path)], cwd=ROOT, capture_output=True, text=True,
                       timeout=300)
    assert p.returncode != 0 and "KeyboardInterrupt" in p.stderr
    from qr import tracking
    from qr.stages.sweep_callback import PARENT_FILE

    run = tracking._client().get_run((tmp_path / PARENT_FILE).read_text().strip())
    assert run.info.status == "FAILED"  # (the exit hook's status: see SweepCallback._open)


def _killed_holding_a_run(tmp_path, script: str) -> None:
    """Run ``script`` (argv[1]: tmp_path) in a process that is SIGKILLed once it has written ``ready``: what it
    opened stays RUNNING (forced by the file, not by timing)."""
    ready = tmp_path / "ready"
    p = subprocess.Popen([sys.executable, "-c", textwrap.dedent(script), str(tmp_path)], cwd=ROOT)
    try:
        while not ready.exists():  # the script either gets there or ends
            assert p.poll() is None, "the script ended before it was ready"
            time.sleep(0.05)
    finally:
        p.kill()
        p.wait()


def test_a_ctrl_c_ends_the_runs_of_sweep_workers_their_pool_killed(tmp_path, monkeypatch):
    """Ctrl-C on a sweep run by joblib: the pool kills its workers, one of them while its job's run was open
    (a hand test of `qr learn -m sweep=table_4_2 hydra/launcher=joblib2`, Ctrl-C after 22 s, left row02
    RUNNING).  Closing the parent on the interrupt ends that run KILLED, saying its process was gone."""
    monkeypatch.setenv("QR_TRACKING", "on")
    from qr import tracking
    from qr.stages.sweep_callback import SweepCallback, parent_id

    sweep = SweepCallback()
    sweep._open(tmp_path, "sweep", {"sweep": "s"})
    _killed_holding_a_run(tmp_path, """
        import sys
        from pathlib import Path
        from qr import tracking
        from qr.stages.sweep_callback import parent_id
        out = Path(sys.argv[1])
        with tracking.run("learn", "row01", {}, parent=tracking.Run(tracking._client(), parent_id(out))):
            (out / "ready").write_text("")
            import time; time.sleep(600)
    """)
    client = tracking._client()
    parent = parent_id(tmp_path)
    child = client.search_runs([client.get_run(parent).info.experiment_id],
                               f"tags.`mlflow.parentRunId` = '{parent}'")[0]
    assert child.info.status == "RUNNING"
    sweep._close(KeyboardInterrupt())
    child = client.get_run(child.info.run_id)
    assert child.info.status == "KILLED" and "ended without closing the run" in child.data.tags["qr.killed"]
    assert client.get_run(parent).info.status == "KILLED"


def test_the_workflow_ends_the_parent_run_of_a_sweep_process_killed_after_ctrl_c(tmp_path, monkeypatch):
    """The workflow's job (workflow/scripts/learn_sweep.py) kills a sweep that does not end within its grace
    after Ctrl-C; what the sweep left open then ends KILLED (a CI run of tests/workflow/test_faults.py left
    table_4_2's parent RUNNING after Ctrl-C)."""
    monkeypatch.setenv("QR_TRACKING", "on")
    from qr import tracking
    from qr.stages.sweep_callback import end_orphaned_runs, parent_id

    _killed_holding_a_run(tmp_path, """
        import sys
        from pathlib import Path
        from qr.stages.sweep_callback import SweepCallback
        SweepCallback()._open(Path(sys.argv[1]), "sweep", {"sweep": "s"})
        (Path(sys.argv[1]) / "ready").write_text("")
        import time; time.sleep(600)
    """)
    parent = parent_id(tmp_path)
    assert tracking._client().get_run(parent).info.status == "RUNNING"
    assert end_orphaned_runs(tmp_path, wait_s=0.0) == [parent]
    assert tracking._client().get_run(parent).info.status == "KILLED"
