"""Whole-workflow runs on the reduced config (conf/workflow_ci.yaml) in scratch working directories.

Shared by the fault, determinism, concurrency and cluster tests.  A run happens in its own
directory with symlinks to the repository's conf/, workflow/, Snakefile and profiles/ (so
profiles/default applies, as in the repository), with ``QR_RESULTS`` and the MLflow store inside
it; /work/main/results is never touched.  Each full run is made once per test session
(memoised here, so the test modules share them).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import re
import signal
import sqlite3
import subprocess
import time
from pathlib import Path

import pandas as pd

from conftest import DATA, ROOT

SNAKEMAKE = str(ROOT / ".venv" / "bin" / "snakemake")
PYTHON = str(ROOT / ".venv" / "bin" / "python")
CI_CONFIG = "conf/workflow_ci.yaml"
HANG_GUARD_S = 1800  # only against a hung run; no assertion is about time

_memo: dict = {}


def workdir(path: Path) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    for name in ("conf", "workflow", "Snakefile", "profiles"):
        if not (path / name).exists():
            (path / name).symlink_to(ROOT / name)
    return path


def env(path: Path, **extra) -> dict:
    e = {k: v for k, v in os.environ.items() if k not in ("MLFLOW_TRACKING_URI", "SNAKEMAKE_PROFILE")}
    e.update({"QR_RESULTS": str(path / "results"), "QR_DATA": str(DATA), "QR_TRACKING": "on"})
    e.update(extra)
    return e


def with_tests_path() -> str:
    """PYTHONPATH with this folder first: processes started by a test import its helpers (sweep_barrier)."""
    return os.pathsep.join([str(Path(__file__).parent), *filter(None, [os.environ.get("PYTHONPATH")])])


def start(path: Path, *args, log: str = "snakemake.log", **extra_env) -> subprocess.Popen:
    """Snakemake in ``path`` in a session of its own (so a signal can go to its process group, as
    Ctrl-C at a terminal sends SIGINT to the whole foreground group)."""
    out = open(path / log, "a")
    return subprocess.Popen([SNAKEMAKE, *args], cwd=path, env=env(path, **extra_env), stdout=out,
                            stderr=subprocess.STDOUT, start_new_session=True)


def snakemake(path: Path, *args, check=True, log: str = "snakemake.log", **extra_env) -> int:
    p = start(path, *args, log=log, **extra_env)
    rc = p.wait(timeout=HANG_GUARD_S)
    if check and rc != 0:
        raise AssertionError(f"snakemake {' '.join(args)} failed ({rc}); log:\n" + tail(path / log))
    return rc


def tail(p: Path, n: int = 60) -> str:
    return "\n".join(Path(p).read_text(errors="replace").splitlines()[-n:]) if Path(p).exists() else ""


def wait_for(condition, proc: subprocess.Popen | None, what: str, poll_s: float = 0.2):
    """Wait until ``condition()`` is truthy (returns it); fail if ``proc`` (if given) ends first."""
    deadline = time.monotonic() + HANG_GUARD_S
    while time.monotonic() < deadline:
        got = condition()
        if got:
            return got
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"the run ended ({proc.returncode}) before {what}")
        time.sleep(poll_s)
    raise AssertionError(f"hang guard: no {what}")


def kill_group(proc: subprocess.Popen, sig) -> int:
    """Send ``sig`` to Snakemake's process group; return Snakemake's exit code once every process of
    the group has ended (so that what the store shows then is final)."""
    os.killpg(proc.pid, sig)
    rc = proc.wait(timeout=HANG_GUARD_S)
    deadline = time.monotonic() + HANG_GUARD_S
    while group_members(proc.pid):
        if time.monotonic() > deadline:
            raise AssertionError(f"processes of group {proc.pid} still run: {group_members(proc.pid)}")
        time.sleep(0.1)
    return rc


def group_members(pgid: int) -> list[str]:
    """Command lines of the live (not zombie) processes of process group ``pgid``."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            cmd = (stat.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, IndexError):
            continue  # gone meanwhile
        if int(fields[2]) == pgid and fields[0] != "Z":
            out.append(f"{stat.parent.name}: {cmd[:200]}")
    return out


# ---- what a run left ---------------------------------------------------------------------------

TIME_COLUMN = re.compile(r"time", re.IGNORECASE)  # wall-clock measurements (train time): not results


def tables(results: Path) -> dict[str, pd.DataFrame]:
    """Every CSV table of a run (MLflow's artifact copies and Hydra's sweep folders aside), without
    wall-clock columns."""
    out = {}
    for p in sorted(results.rglob("*.csv")):
        rel = p.relative_to(results)
        if rel.parts[0] in ("mlartifacts", "hydra", "benchmarks") or "hydra" in rel.parts:
            continue
        df = pd.read_csv(p)
        out[str(rel)] = df[[c for c in df.columns if not TIME_COLUMN.search(str(c))]]
    return out


def broken_outputs(results: Path) -> list[str]:
    """Outputs that are not whole: a CSV/Parquet/JSON that does not parse, a PNG without its end chunk,
    an empty file.  Write-then-rename temporaries (hidden, named ``.*.qrtmp-*``) are not outputs."""
    bad = []
    for p in results.rglob("*"):
        if not p.is_file() or p.name.startswith(".") or "mlartifacts" in p.parts or p.name.startswith("mlflow."):
            continue
        try:
            if p.stat().st_size == 0 and p.suffix not in (".log",):
                raise ValueError("empty")
            if p.suffix == ".csv":
                pd.read_csv(p)
            elif p.suffix == ".parquet":
                pd.read_parquet(p)
            elif p.suffix == ".json":
                json.loads(p.read_text())
            elif p.suffix == ".png":
                data = p.read_bytes()
                if not (data.startswith(b"\x89PNG") and data.endswith(b"IEND\xaeB`\x82")):
                    raise ValueError("truncated PNG")
        except Exception as e:  # noqa: BLE001 - any failure to read is a broken output
            bad.append(f"{p.relative_to(results)}: {e}")
    return bad


def temporaries(results: Path) -> list[Path]:
    return [p for p in results.rglob("*") if ".qrtmp-" in p.name]


def client(results: Path):
    import mlflow

    os.environ.setdefault("MLFLOW_SQLALCHEMYSTORE_POOLCLASS", "NullPool")
    return mlflow.MlflowClient(tracking_uri=f"sqlite:///{results / 'mlflow.db'}")


def all_runs(results: Path) -> dict:
    """run id -> Run, every run of every experiment of the store."""
    from mlflow.entities import ViewType

    c = client(results)
    exps = [e.experiment_id for e in c.search_experiments(view_type=ViewType.ALL)]
    runs, token = {}, None
    while exps:
        page = c.search_runs(exps, "", ViewType.ALL, 1000, None, token)
        runs.update({r.info.run_id: r for r in page})
        token = page.token
        if not token:
            break
    return runs


def integrity(results: Path) -> str:
    con = sqlite3.connect(f"file:{results / 'mlflow.db'}?mode=ro", uri=True)
    try:
        return con.execute("PRAGMA integrity_check").fetchone()[0]
    finally:
        con.close()


def running(results: Path, stage: str | None = None) -> set[str]:
    """Ids of the runs the store has RUNNING now (read-only SQL, so writers are not held up)."""
    return stored(results, stage, "RUNNING")


def stored(results: Path, stage: str | None = None, status: str | None = None) -> set[str]:
    """Ids of the runs the store holds (of ``stage``, with ``status``), read-only SQL as :func:`running`."""
    db = results / "mlflow.db"
    if not db.exists():
        return set()
    sql = "SELECT run_uuid FROM runs WHERE 1 = 1"
    args = ()
    if status:
        sql += " AND status = ?"
        args += (status,)
    if stage:
        sql += " AND run_uuid IN (SELECT run_uuid FROM tags WHERE key = 'qr.stage' AND value = ?)"
        args += (stage,)
    try:
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
        try:
            return {r[0] for r in con.execute(sql, args)}
        finally:
            con.close()
    except sqlite3.Error:  # the store is being created
        return set()


@contextlib.contextmanager
def store_held(results: Path):
    """The tracking store's lock file (qr.tracking takes it to open every run), held by the test: a
    process opening a run waits until the block ends.  Yields the lock file's path."""
    lock = results / "mlflow.lock"
    with open(lock, "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield lock
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def waiting_for(lock: Path) -> bool:
    """Does a process wait for the flock of ``lock``?  (Linux's /proc/locks marks a waiter with ``->``:
    ``1: -> FLOCK ADVISORY WRITE <pid> <major>:<minor>:<inode> 0 EOF``.)"""
    inode = str(lock.stat().st_ino)
    for line in Path("/proc/locks").read_text().splitlines():
        parts = line.split()
        if len(parts) > 6 and parts[1] == "->" and parts[2] == "FLOCK" and parts[6].split(":")[-1] == inode:
            return True
    return False


def parent_files(results: Path) -> dict[str, str]:
    """Open sweep parent runs: ``.mlflow_parent`` files of the learning sweeps (path -> run id)."""
    out = {}
    for p in (results / "learn").glob("*/.mlflow_parent"):
        try:
            out[str(p)] = p.read_text().strip()
        except OSError:
            pass
    return {k: v for k, v in out.items() if v}


# ---- the two full runs -------------------------------------------------------------------------

def clean_run(tmp_path_factory) -> Path:
    """One uninterrupted `snakemake --cores 2 --configfile conf/workflow_ci.yaml`; its results dir.

    Without MLflow tracking (QR_TRACKING=off): it is compared by its tables, which tracking does not
    touch, and it saves every job the MLflow start-up."""
    if "clean" not in _memo:
        path = workdir(tmp_path_factory.mktemp("ci_clean"))
        snakemake(path, "--cores", "2", "--configfile", CI_CONFIG, QR_TRACKING="off")
        _memo["clean"] = path / "results"
    return _memo["clean"]


def faulted_run(tmp_path_factory) -> dict:
    """The same workflow, interrupted twice and resumed with the plain command each time:

    1. Ctrl-C (SIGINT to the whole process group) while a learning sweep has its MLflow parent run open;
    2. rerun, then SIGKILL to the whole group (nothing can clean up) while a resumed sweep has its
       parent run open;
    3. rerun: refused (the killed run's lock); ``snakemake --unlock``; rerun: it must complete.

    The sweeps' parent runs are open when the signals come, forced rather than hoped for: each sweep,
    its jobs done, waits before it closes its parent run (sweep_barrier, a Hydra callback added to the
    sweeps' overrides by a second config file) until the file ``release`` exists, made before step 3's
    last rerun.  (The barrier changes no table: it is a `hydra.` override, and only delays.)

    Returns what was observed after each step (return codes, the store's runs, lock and
    incomplete markers, broken outputs)."""
    if "faulted" in _memo:
        return _memo["faulted"]
    import yaml

    from sweep_barrier import barrier_overrides

    path = workdir(tmp_path_factory.mktemp("ci_faulted"))
    results = path / "results"
    ci = yaml.safe_load((ROOT / CI_CONFIG).read_text())
    barrier = {"learn": {"overrides": [*ci["learn"]["overrides"], *barrier_overrides(path / "release", "multirun_end")]}}
    (path / "barrier.yaml").write_text(yaml.safe_dump(barrier))
    args = ("--cores", "2", "--configfile", CI_CONFIG, "barrier.yaml")
    obs = {"path": path, "results": results, "args": args}
    env = {"PYTHONPATH": with_tests_path()}  # the sweeps import sweep_barrier

    p = start(path, *args, **env)
    wait_for(lambda: parent_files(results), p, "a learning sweep opened its parent run")
    obs["sigint_open"] = running(results)
    obs["sigint_ms"] = int(time.time() * 1000)  # runs that end after this were ended by the Ctrl-C
    obs["sigint_rc"] = kill_group(p, signal.SIGINT)
    obs["sigint_parents"] = set(parent_files(results).values())
    obs["after_sigint"] = all_runs(results)
    obs["after_sigint_broken"] = broken_outputs(results)
    obs["locks_after_sigint"] = sorted(x.name for x in (path / ".snakemake" / "locks").glob("*"))

    seen = set(parent_files(results).values())
    p = start(path, *args, **env)
    new = wait_for(lambda: set(parent_files(results).values()) - seen, p, "a resumed sweep opened its parent run")
    obs["sigkill_rc"] = kill_group(p, signal.SIGKILL)
    obs["sigkill_parents"] = new
    obs["after_sigkill"] = all_runs(results)
    obs["after_sigkill_broken"] = broken_outputs(results)
    obs["locks_after_sigkill"] = sorted(x.name for x in (path / ".snakemake" / "locks").glob("*"))
    obs["incomplete_after_sigkill"] = sorted(x.name for x in (path / ".snakemake" / "incomplete").rglob("*")
                                             if x.is_file())

    obs["locked_rc"] = snakemake(path, *args, check=False, **env)
    obs["locked_log"] = (path / "snakemake.log").read_text(errors="replace")
    snakemake(path, "--unlock", **env)
    (path / "release").touch()  # the sweeps may end now
    obs["resume_rc"] = snakemake(path, *args, check=False, **env)
    obs["resume_log"] = (path / "snakemake.log").read_text(errors="replace")
    obs["final"] = all_runs(results)
    _memo["faulted"] = obs
    return obs
