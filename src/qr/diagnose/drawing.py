"""The report's figures, started early: matplotlib imported on a thread while the filters run (their compiled
kernels release the GIL: a third of a second a user no longer waits for), and the residual anatomy drawn by a
forked child while the fit runs (it needs only the nominal residuals, :mod:`qr.report.background`)."""

from __future__ import annotations

import threading


class Drawing:
    """One diagnosis's early drawing; a context: the child is stopped and removed however the run ends."""

    def __init__(self, vehicle):
        self._vehicle = vehicle
        self._thread = threading.Thread(target=self._load, daemon=True)
        self.anatomy = None  # the residual anatomy's BackgroundFigure, once the labels exist

    def __enter__(self) -> Drawing:
        return self

    def __exit__(self, *exc) -> None:
        if self.anatomy is not None:
            self.anatomy.close()

    @staticmethod
    def _load():
        from . import report  # noqa: F401  (imports qr.report.figures, matplotlib)

    def start(self) -> None:
        """Import the plotting on a thread (once the flights passed their checks)."""
        self._thread.start()

    def ready(self) -> None:
        """Wait for the import: before any fork, a child must not inherit an import half done."""
        if self._thread.is_alive() or self._thread.ident is not None:
            self._thread.join()

    def draw_anatomy(self, prep) -> None:
        """:func:`qr.diagnose.run`'s ``on_labels``: the anatomy drawn by a child from the full-flight labels."""
        from ..report.background import BackgroundFigure
        from .report import anatomy_figure

        self.anatomy = BackgroundFigure(lambda path: anatomy_figure(prep, self._vehicle, path))
