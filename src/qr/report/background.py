"""A figure drawn in a forked child while the parent computes on.

matplotlib holds the GIL, so a thread would not help; a forked child shares the parent's data without
pickling, and on two cores its drawing is hidden behind the parent's work (the diagnosis's residual
anatomy, 36 panels, behind the selection). Linux only (macOS forbids fork after threads); elsewhere,
or when the child fails, the figure is drawn in the parent when it is collected, so the result is the
same file either way.
"""

from __future__ import annotations

import os
import shutil
import signal
import sys
import tempfile
from pathlib import Path


class BackgroundFigure:
    """``draw(path)`` writes a PNG; started now, moved to its place by :meth:`collect`."""

    def __init__(self, draw):
        self._draw = draw
        self._dir = Path(tempfile.mkdtemp(prefix="qr-figure-"))
        self._tmp = self._dir / "figure.png"
        self._pid = None
        if sys.platform.startswith("linux"):
            sys.stdout.flush()
            sys.stderr.flush()
            pid = os.fork()
            if pid == 0:  # the child: draw, and never return into the parent's code
                code = 1
                try:
                    signal.signal(signal.SIGINT, signal.SIG_DFL)
                    signal.signal(signal.SIGTERM, signal.SIG_DFL)
                    draw(self._tmp)
                    code = 0
                finally:
                    os._exit(code)
            self._pid = pid

    def collect(self, path: str | Path) -> None:
        """Wait for the child and move its figure to ``path`` (drawn here if the child failed)."""
        try:
            done = False
            if self._pid is not None:
                _, status = os.waitpid(self._pid, 0)
                self._pid = None
                done = os.waitstatus_to_exitcode(status) == 0 and self._tmp.exists()
            if not done:
                self._draw(self._tmp)
            shutil.move(self._tmp, path)
        finally:
            self.close()

    def close(self) -> None:
        """Stop the child if it still runs and remove its folder (a failed or interrupted run)."""
        if self._pid is not None:
            try:
                os.kill(self._pid, signal.SIGKILL)
                os.waitpid(self._pid, 0)
            except (ProcessLookupError, ChildProcessError):
                pass
            self._pid = None
        shutil.rmtree(self._dir, ignore_errors=True)
