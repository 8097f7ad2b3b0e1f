"""The base of the stages' Hydra sweep callbacks (``qr learn -m``, ``qr learn residual -m``)."""

from __future__ import annotations

try:
    from hydra.experimental.callback import Callback
except ImportError:  # pragma: no cover
    Callback = object

PARENT_FILE = ".mlflow_parent"  # in a sweep's output folder: the id of its MLflow parent run, for every job


class SweepCallback(Callback):
    """Launchers pickle the callbacks along with each job; a worker needs none of the parent's state (an
    open MLflow run, a progress bar), so a callback is pickled empty and starts afresh."""

    def __init__(self):
        self.reset()

    def reset(self) -> None:
        """Set the callback's per-sweep state to nothing (a subclass adds its own)."""
        self._cm = None  # the parent MLflow run's context manager while the sweep runs

    def _close(self, exc) -> None:
        """End the parent run: finished, or with ``exc`` (failed, or killed by a signal) if the sweep raised."""
        if self._cm is None:
            return
        cm, self._cm = self._cm, None
        if exc is None:
            cm.__exit__(None, None, None)
        else:
            try:
                cm.__exit__(type(exc), exc, None)
            except type(exc):
                pass

    def __getstate__(self):
        return {}

    def __setstate__(self, state):
        self.__init__()
