"""A Hydra callback for the tests: a sweep waits at a barrier until a file exists.

Added on the command line (the sweep's processes need this folder on PYTHONPATH)::

    +hydra.callbacks.barrier._target_=sweep_barrier.WaitForFile +hydra.callbacks.barrier.path=/tmp/x/release
    [+hydra.callbacks.barrier.at=multirun_end]

``at=job_start`` (default): every job waits before it starts; ``at=multirun_end``: the sweep, its jobs
done, waits before it ends (Hydra calls the end callbacks in reverse order: before
qr.stages.learn_sets.LearnSweep closes the parent run).  Either way the sweep's MLflow parent run is open
while it waits, so a test decides when the sweep writes or ends: it forces what it needs (an overlap
with another writer, an interrupt while the parent run is open) instead of hoping for it.
"""

import time
from pathlib import Path

from hydra.experimental.callback import Callback

HANG_GUARD_S = 1800  # only against a test that died without releasing the sweep
POINTS = ("job_start", "multirun_end")


def barrier_overrides(path, at: str = "job_start") -> list[str]:
    """The Hydra overrides that add the barrier to a sweep."""
    assert at in POINTS, at
    return ["+hydra.callbacks.barrier._target_=sweep_barrier.WaitForFile", f"+hydra.callbacks.barrier.path={path}",
            f"+hydra.callbacks.barrier.at={at}"]


class WaitForFile(Callback):
    def __init__(self, path: str, at: str = "job_start"):
        assert at in POINTS, at
        self.path, self.at = str(path), at

    def _wait(self) -> None:
        deadline = time.monotonic() + HANG_GUARD_S
        while not Path(self.path).exists():
            if time.monotonic() > deadline:
                raise RuntimeError(f"sweep_barrier: {self.path} never appeared")
            time.sleep(0.05)

    def on_job_start(self, config, **kwargs) -> None:
        if self.at == "job_start":
            self._wait()

    def on_multirun_end(self, config, **kwargs) -> None:
        if self.at == "multirun_end":
            self._wait()
