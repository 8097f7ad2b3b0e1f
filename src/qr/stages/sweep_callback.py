"""The base of the stages' Hydra sweep callbacks (``qr learn -m``, ``qr learn residual -m``): the sweep's MLflow
parent run, opened at the multirun's start and closed at its end."""

from __future__ import annotations

from pathlib import Path

try:
    from hydra.experimental.callback import Callback
except ImportError:  # pragma: no cover
    Callback = object

PARENT_FILE = ".mlflow_parent"  # in a sweep's output folder: the id of its MLflow parent run, for every job


def parent_id(out) -> str | None:
    """The id of the parent run of the sweep writing into ``out`` (None outside a sweep)."""
    parent = Path(out) / PARENT_FILE
    return parent.read_text().strip() if parent.exists() else None


class SweepCallback(Callback):
    """Launchers pickle the callbacks along with each job; a worker needs none of the parent's state (an
    open MLflow run, a progress bar), so a callback is pickled empty and starts afresh."""

    JOB = ""  # the Hydra job name of the multiruns this callback acts for

    def __init__(self):
        self.reset()

    def reset(self) -> None:
        """Set the callback's per-sweep state to nothing (a subclass adds its own)."""
        self._cm = self._run = None  # the parent MLflow run (its context manager) while the sweep runs

    def mine(self, config) -> bool:
        try:
            return config.hydra.job.name == self.JOB
        except Exception:
            return False

    def _open(self, out: Path, name: str, params: dict, tags: dict | None = None) -> None:
        """Open the parent run and write its id to ``out/PARENT_FILE``, where every job (in this process or a
        worker) finds it.  If a job fails or the sweep is interrupted, Hydra never calls the end hook: the run is then
        closed FAILED at exit (an interrupt too: ``qr`` ends on it quietly, with exit status 130, and the hook
        cannot tell).  A Ctrl-C before that is arranged (while the file is written, say) closes the run KILLED at once: a run
        entered by hand, not by ``with``, is otherwise left RUNNING."""
        import atexit

        from .. import tracking
        from ..atomic import write_text

        tags = {"qr.sweep": name, "qr.parent": "true", **(tags or {})}
        self._cm = tracking.run("learn", name, config=params, tags=tags)
        try:
            self._run = self._cm.__enter__()
            write_text(out / PARENT_FILE, self._run.id + "\n")  # (a reader never finds it empty)
            atexit.register(self._close, RuntimeError("a job of the sweep failed"))
        except BaseException as e:
            self._close(e)
            raise

    def _close(self, exc) -> None:
        """End the parent run: finished, or with ``exc`` (failed, or killed by a signal) if the sweep raised."""
        if self._cm is None:
            return
        cm, self._cm = self._cm, None
        if exc is None:
            cm.__exit__(None, None, None)
        else:
            from .. import tracking

            try:  # a worker the pool killed on Ctrl-C leaves its job's run RUNNING: end it before the parent
                tracking.reap_sweep(self._run.id, wait_s=10.0)
            except Exception as e:  # never let it keep the parent open
                import logging

                logging.getLogger("qr.tracking").warning("could not end the sweep's jobs' runs: %s", e)
            try:
                cm.__exit__(type(exc), exc, None)
            except type(exc):
                pass

    def __getstate__(self):
        return {}

    def __setstate__(self, state):
        self.__init__()


def end_orphaned_runs(out, wait_s: float = 30.0) -> list[str]:
    """After the sweep writing into ``out`` was interrupted and its process has ended: the runs its processes
    left RUNNING (killed before they could end them) end KILLED (:func:`qr.tracking.reap_sweep`)."""
    from .. import tracking

    parent = parent_id(out)
    return tracking.reap_sweep(parent, wait_s) if parent else []
