"""MLflow runs with provenance: the one way the project opens a tracked run.

Store: ``MLFLOW_TRACKING_URI``, else SQLite ``results/mlflow.db`` (``QR_RESULTS`` moves ``results``); one
experiment per stage; every run tagged with the git commit, a hash of its config and a digest of its inputs.
SQLite allows one writer: writes are retried and store creation is locked.  A run ends FINISHED, FAILED or
KILLED (SIGINT/SIGTERM); runs a dead process left RUNNING are marked KILLED by the next (:func:`reap_stale`).
docs/workflow.md "Interrupting and resuming".
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import logging
import os
import random
import subprocess
import time
import uuid
import warnings
from pathlib import Path
from typing import Iterable, Iterator

from .procs import Terminated  # noqa: F401  (SIGTERM as an exception: qr.procs.sigterm_raises)

_RETRIES = 12
_reaped = False


def results_dir() -> Path:
    return Path(os.environ.get("QR_RESULTS", "results")).resolve()


def tracking_uri() -> str:
    uri = os.environ.get("MLFLOW_TRACKING_URI")
    if uri:
        return uri
    return f"sqlite:///{results_dir() / 'mlflow.db'}"


def _is_local_sqlite(uri: str) -> bool:
    return uri.startswith("sqlite:///")


@contextlib.contextmanager
def _store_lock() -> Iterator[None]:
    uri = tracking_uri()
    if not _is_local_sqlite(uri):
        yield
        return
    lock = Path(uri[len("sqlite:///"):]).with_suffix(".lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    with open(lock, "w") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _retry(fn, *args, **kwargs):
    """Call ``fn`` retrying on SQLite's 'database is locked' under concurrent writers."""
    for attempt in range(_RETRIES):
        try:
            return fn(*args, **kwargs)
        except Exception as e:  # mlflow wraps sqlalchemy errors in MlflowException
            msg = str(e).lower()
            if "locked" not in msg and "busy" not in msg or attempt == _RETRIES - 1:
                raise
            time.sleep(0.05 * 2 ** min(attempt, 6) * (0.5 + random.random()))


def git_commit() -> str:
    try:
        root = Path(__file__).resolve().parents[2]
        res = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                             timeout=5)
        sha = res.stdout.strip() if res.returncode == 0 else ""
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=5).stdout.strip()
        return (sha or "unknown") + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def config_hash(config) -> str:
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()[:16]


def data_digest(paths: Iterable[str | Path]) -> str:
    """Digest of the inputs' names and bytes; a directory counts as its files (relative names, sorted)."""
    h = hashlib.sha256()
    for p in sorted(str(p) for p in paths):
        p = Path(p)
        h.update(p.name.encode())
        files = sorted(f for f in p.rglob("*") if f.is_file()) if p.is_dir() else [p]
        for fp in files:
            if fp != p:
                h.update(str(fp.relative_to(p)).encode())
            with open(fp, "rb") as f:
                for chunk in iter(lambda: f.read(1 << 20), b""):
                    h.update(chunk)
    return h.hexdigest()[:16]


def flatten(d, prefix="") -> dict:
    out = {}
    for k, v in (d or {}).items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, key + "."))
        else:
            out[key] = v
    return out


def _client():
    import mlflow

    logging.getLogger("alembic").setLevel(logging.WARNING)
    logging.getLogger("mlflow").setLevel(logging.WARNING)
    os.environ.setdefault("MLFLOW_SQLALCHEMYSTORE_POOLCLASS", "NullPool")
    mlflow.set_tracking_uri(tracking_uri())
    return mlflow.MlflowClient()


# what each experiment holds: the MLflow UI shows it as the experiment's description
DESCRIPTIONS = {
    "ingest": "Raw logs to canonical flights: one run per flight set summary (samples, dropouts, rates).",
    "filter": "State estimation per flight (position KF, attitude ESKF on SO(3), rotor-speed KF, smoother): "
              "tuned noise, NIS consistency, run time.",
    "learn": "Residual force/torque models (ANN, linear, GPR): one run per model, sweeps as parent runs; "
             "test RMSE and its ratio to the nominal model's.",
    "diagnose": "qr diagnose: named effects with parameters and standard errors, nominal vs extended held-out "
                "RMSE, replay and rollout.",
    "simulate": "Closed-loop tracking study (LQR + PD on a Bezier trajectory), thesis Chapter 5: position RMSE "
                "per controller and residual model.",
    "evaluate": "Multi-step rollout on held-out flights (docs/spec/evaluate.md): MAE at the horizon per "
                "model and its ratio to the benchmark's physics baseline (rate_frozen).",
    "stability": "Eq. 5.15 stability analysis of the closed loop with each learned linear model.",
}
NOTE = "mlflow.note.content"  # an experiment's or a run's description (Markdown in the UI)
# qr's experiments are model training (MLflow 3 opens in its GenAI view: traces, no runs table).  The tag
# declares it; MLflow 3.17's UI follows its GenAI / Model training switch instead, which an address's
# ``workflowType=machine_learning`` sets (UI_QUERY: make mlflow-ui prints such an address)
KIND = {"mlflow.experimentKind": "custom_model_development"}
UI_QUERY = "workflowType=machine_learning"
# the metrics each stage's runs table leads with: MLflow shows none by default (only a shared view, a URL's
# viewStateShareKey naming an experiment tag mlflow.sharedViewState.<key>, selects columns)
RESULTS_VIEW = "results"
LEADING_METRICS = {
    "learn": ["rmse", "ratio", "nominal_rmse", "train_time_s"],
    "diagnose": ["effects_named", "nominal_loss", "extended_loss", "replay.nominal_position_rmse",
                 "replay.extended_position_rmse", "rollout.extended.p_ratio", "rollout.extended.w_ratio"],
    "evaluate": [f"{m}.{q}_ratio" for m in ("nominal", "extended", "physical_refined", "hybrid") for q in ("p", "w")],
    "filter": ["nis.position.mean", "nis.attitude.mean", "inconsistent_filters", "seconds"],
}
LEADING_PARAMS = {"learn": ["inputs", "target", "model.kind", "model.layers", "model.neurons"]}


def _results_view(stage: str) -> str:
    """The shared view (JSON, as the UI's Share button stores it) whose runs table leads with the stage's
    metrics, in this order."""
    cols = [f"metrics.`{m}`" for m in LEADING_METRICS.get(stage, [])]
    cols += [f"params.`{p}`" for p in LEADING_PARAMS.get(stage, [])]
    return json.dumps({"selectedColumns": cols, "columnOrder": cols, "orderByKey": "attributes.start_time",
                       "orderByAsc": False})


def results_view_url(base: str, experiment: str) -> str:
    """The MLflow UI address of an experiment's runs table in its results view (model-training mode).
    ``base`` "": the link an experiment's description holds (a query of its own before the ``#``, so the
    UI loads the view afresh even from the experiment's own page)."""
    return f"{base or '?view=' + RESULTS_VIEW}#/experiments/{experiment}/runs?{UI_QUERY}&viewStateShareKey={RESULTS_VIEW}"


def _experiment_tags(stage: str, experiment: str | None) -> dict:
    """Kind, description and (for a stage with leading metrics) the results view, linked first in the
    description (the UI shows its first line)."""
    tags, note = dict(KIND), DESCRIPTIONS.get(stage, "")
    if stage in LEADING_METRICS:
        tags[f"mlflow.sharedViewState.{RESULTS_VIEW}"] = _results_view(stage)
        if experiment is not None:
            note = (f"[Runs with their results]({results_view_url('', experiment)}) (the table leads with "
                    f"{', '.join(LEADING_METRICS[stage][:3])}, ...) · {note}")
    return {**tags, **({NOTE: note} if note else {})}


def experiment_id(stage: str) -> str:
    """Experiment ``qr-<stage>``, created once (under the lock) if missing, with its description, the
    model-training view and the results view (tags brought up to date on an existing one)."""
    name = f"qr-{stage}"
    with _store_lock():
        client = _client()
        exp = _retry(client.get_experiment_by_name, name)
        if exp is None:
            location = None
            if _is_local_sqlite(tracking_uri()):
                location = (results_dir() / "mlartifacts").as_uri()
            exp = _retry(client.get_experiment, _retry(client.create_experiment, name, artifact_location=location,
                                                       tags=_experiment_tags(stage, None)))
        for key, value in _experiment_tags(stage, exp.experiment_id).items():
            if exp.tags.get(key) != value:
                _retry(client.set_experiment_tag, exp.experiment_id, key, value)
        return exp.experiment_id


class Run:
    """A tracked run; methods retry on a busy store."""

    def __init__(self, client, run_id):
        self.client = client
        self.id = run_id

    def params(self, params: dict) -> None:
        from mlflow.entities import Param

        items = [Param(k, str(v)[:6000]) for k, v in flatten(params).items()]
        for i in range(0, len(items), 100):
            _retry(self.client.log_batch, self.id, params=items[i:i + 100])

    def metrics(self, metrics: dict, step: int = 0) -> None:
        from mlflow.entities import Metric

        now = int(time.time() * 1000)
        items = [Metric(k, float(v), now, step) for k, v in flatten(metrics).items()
                 if v is not None and _finite(v)]
        for i in range(0, len(items), 100):
            _retry(self.client.log_batch, self.id, metrics=items[i:i + 100])

    def tags(self, tags: dict) -> None:
        from mlflow.entities import RunTag

        _retry(self.client.log_batch, self.id, tags=[RunTag(k, str(v)) for k, v in tags.items()])

    def artifact(self, path: str | Path, subdir: str | None = None) -> None:
        _retry(self.client.log_artifact, self.id, str(path), subdir)

    def describe(self, text: str) -> None:
        """The run's description (Markdown; the first thing its page shows)."""
        self.tags({NOTE: text})

    def model(self, flavor: str, obj, X_example, y_example, requirements: list[str],
              name: str = "model", **save_options) -> None:
        """A model in MLflow's ``flavor`` (``pytorch`` / ``sklearn``) with its signature and an input
        example, under artifact path ``name`` (``mlflow.pyfunc.load_model("runs:/<id>/model")``).
        Saved locally and logged as the run's artifacts: qr's runs are client runs, not fluent ones."""
        import importlib
        import tempfile

        from mlflow.models import infer_signature

        save = importlib.import_module(f"mlflow.{flavor}").save_model
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / name
            save(obj, str(path), signature=infer_signature(X_example, y_example), input_example=X_example,
                 pip_requirements=requirements, **save_options)
            _retry(self.client.log_artifacts, self.id, str(path), name)

    def dataset(self, path: str | Path, table, context: str = "training") -> None:
        """The data set as the run's input (the UI's "Datasets used"): name, source, schema and qr's
        content digest, so runs on the same data are found by it."""
        import mlflow.data
        from mlflow.entities import DatasetInput, InputTag

        with warnings.catch_warnings():  # MLflow registers its local-file source twice and warns that a path
            warnings.filterwarnings("ignore", message="The specified dataset source can be interpreted in multiple ways")
            ds = mlflow.data.from_pandas(table, source=str(Path(path).resolve()), name=Path(path).stem,
                                         digest=data_digest([path])[:16])
        _retry(self.client.log_inputs, self.id,
               [DatasetInput(ds._to_mlflow_entity(), [InputTag("mlflow.data.context", context)])])


def _finite(v) -> bool:
    try:
        import math

        return math.isfinite(float(v))
    except (TypeError, ValueError):
        return False


def reap_stale(client=None) -> list[str]:
    """Mark runs left RUNNING by a process of this host that is gone (SIGKILL, crash) as KILLED.

    A run's process is its tags ``qr.host``, ``qr.pid``, ``qr.pid_start``; it is gone when no
    process with that pid and start time runs (or it is a zombie).  Runs of other hosts, and runs
    without these tags, are left alone.  The marked runs get the tag ``qr.killed`` saying who
    noticed.  Returns their ids.  Called once per process by :func:`run`.
    """
    from mlflow.entities import ViewType

    from . import procs

    client = client or _client()
    exps = [e.experiment_id for e in _retry(client.search_experiments, view_type=ViewType.ALL)]
    if not exps:
        return []
    filt = f"attributes.status = 'RUNNING' and tags.`qr.host` = '{procs.host()}'"
    stale, token = [], None
    while True:
        page = _retry(client.search_runs, exps, filt, ViewType.ALL, 1000, None, token)
        for r in page:
            t = r.data.tags
            if "qr.pid" in t and not procs.alive(t["qr.pid"], t.get("qr.pid_start"), t.get("qr.host")):
                stale.append(r)
        token = page.token
        if not token:
            break
    me = procs.identity()
    for r in stale:
        t = r.data.tags
        note = (f"process {t['qr.pid']} on {t['qr.host']} ended without closing the run (SIGKILL or crash); "
                f"marked KILLED by process {me['pid']} at {time.strftime('%Y-%m-%dT%H:%M:%S%z')}")
        Run(client, r.info.run_id).tags({"qr.killed": note})
        _retry(client.set_terminated, r.info.run_id, "KILLED")
    return [r.info.run_id for r in stale]


def reap_sweep(parent: str, wait_s: float = 30.0, client=None) -> list[str]:
    """After an interrupted sweep: its runs (the parent ``parent`` and its children) that a process left
    RUNNING are marked KILLED as :func:`reap_stale` marks them, waiting up to ``wait_s`` for the processes still
    ending (a worker its pool killed while it closed its run).  This process's own runs are not waited for.
    Returns the runs marked."""
    if os.environ.get("QR_TRACKING", "on").lower() in ("off", "0", "false"):
        return []
    client = client or _client()
    exp = _retry(client.get_run, parent).info.experiment_id
    children = f"attributes.status = 'RUNNING' and tags.`mlflow.parentRunId` = '{parent}'"
    me, deadline, marked = str(os.getpid()), time.monotonic() + wait_s, []
    while True:
        marked += reap_stale(client)
        runs = [_retry(client.get_run, parent), *_retry(client.search_runs, [exp], children)]
        if not [r for r in runs if r.info.status == "RUNNING" and r.data.tags.get("qr.pid") != me] \
                or time.monotonic() > deadline:
            return marked
        time.sleep(0.2)


def _reap_once(client) -> None:
    global _reaped
    if _reaped:
        return
    _reaped = True
    try:
        reap_stale(client)
    except Exception as e:  # never let the clean-up of someone else's run fail this one
        logging.getLogger("qr.tracking").warning("could not check for stale runs: %s", e)


@contextlib.contextmanager
def run(stage: str, name: str, config: dict | None = None, inputs: Iterable[str | Path] = (),
        parent: Run | None = None, tags: dict | None = None, description: str | None = None) -> Iterator[Run]:
    """Open an MLflow run in experiment ``qr-<stage>`` with provenance tags; ``description``: the run's
    (its page shows it first; :meth:`Run.describe` sets it later).

    Ends FINISHED on success, KILLED on interrupt (SIGINT, SIGTERM), FAILED on any other error.
    ``QR_TRACKING=off`` disables tracking (the run object then records nothing).
    """
    if os.environ.get("QR_TRACKING", "on").lower() in ("off", "0", "false"):
        yield _NullRun()
        return
    from . import procs

    exp = experiment_id(stage)
    client = _client()
    _reap_once(client)
    inputs = list(inputs)
    me = procs.identity()
    all_tags = {
        "qr.stage": stage,
        "mlflow.source.git.commit": git_commit(),
        "qr.config_hash": config_hash(config or {}),
        "qr.data_digest": data_digest(inputs) if inputs else "none",
        "qr.inputs": ",".join(Path(p).name for p in inputs)[:5000],
        "qr.host": me["host"], "qr.pid": me["pid"], "qr.pid_start": me["start"],
    }
    if parent is not None and not isinstance(parent, _NullRun):
        all_tags["mlflow.parentRunId"] = parent.id
    all_tags.update(tags or {})
    if description:
        all_tags[NOTE] = description
    # a cancel that lands inside create_run (the run stored, its id not yet returned) must still end the
    # run: the token finds it (masking the signal is not enough: another thread of the process takes it)
    token = uuid.uuid4().hex
    all_tags["qr.run_token"] = token
    with procs.sigterm_raises():
        handle, status = None, "FAILED"
        try:
            r = _retry(client.create_run, exp, run_name=name, tags={k: str(v) for k, v in all_tags.items()})
            handle = Run(client, r.info.run_id)
            if config:
                handle.params(config)
            yield handle
            status = "FINISHED"
        except BaseException as e:  # SIGINT, or SIGTERM (Terminated), possibly wrapped by a compiled call
            if procs.interrupt_in(e) is not None:
                status = "KILLED"
            raise
        finally:
            with procs.signals_held():
                ids = [handle.id] if handle is not None else [
                    x.info.run_id for x in client.search_runs([exp], filter_string=f"tags.`qr.run_token` = '{token}'")]
                for run_id in ids:
                    _retry(client.set_terminated, run_id, status)


class _NullRun(Run):
    def __init__(self):
        super().__init__(None, "none")

    def params(self, params):
        pass

    def metrics(self, metrics, step=0):
        pass

    def tags(self, tags):
        pass

    def artifact(self, path, subdir=None):
        pass

    def describe(self, text):
        pass

    def model(self, flavor, obj, X_example, y_example, requirements, name="model", **save_options):
        pass

    def dataset(self, path, table, context="training"):
        pass
