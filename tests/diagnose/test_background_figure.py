"""The residual anatomy drawn by a forked child while the selection runs (``qr.report.background``):
the same file as drawn in the parent, a failed child redrawn in the parent, nothing left behind when a
diagnosis stops early."""

from __future__ import annotations

import os
import sys
import tempfile

import pytest

from qr.report.background import BackgroundFigure

linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="drawn in the parent elsewhere")


def _draw_figure(path):
    from qr.report import figures

    fig, ax = figures.subplots(2, 2, figsize=(4, 3))
    ax[0, 0].plot([0, 1, 2], [1, 0, 2])
    figures.save(fig, path, tight=False)


@pytest.fixture
def private_tmp(tmp_path, monkeypatch):
    """The child's scratch folders go here, so the test can see what is left."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "scratch"))
    (tmp_path / "scratch").mkdir()
    return tmp_path / "scratch"


def _gone(pid):
    """The child ``pid`` was waited for (no zombie, nothing running): only the test's own child is asked,
    other tests of the same worker may have children of their own."""
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)
    return True


@linux
def test_the_child_draws_the_file_the_parent_would(tmp_path, private_tmp):
    parent = os.getpid()
    drawn_by = tmp_path / "who"

    def draw(path):
        drawn_by.write_text("child" if os.getpid() != parent else "parent")
        _draw_figure(path)

    bg = BackgroundFigure(draw)
    pid = bg._pid
    bg.collect(tmp_path / "forked.png")
    assert drawn_by.read_text() == "child"
    _draw_figure(tmp_path / "here.png")
    assert (tmp_path / "forked.png").read_bytes() == (tmp_path / "here.png").read_bytes()
    assert list(private_tmp.iterdir()) == [] and _gone(pid)


@linux
def test_a_failed_child_is_redrawn_in_the_parent(tmp_path, private_tmp):
    parent = os.getpid()

    def draw(path):
        if os.getpid() != parent:
            raise RuntimeError("the child fails")
        _draw_figure(path)

    bg = BackgroundFigure(draw)
    pid = bg._pid
    bg.collect(tmp_path / "f.png")
    assert (tmp_path / "f.png").stat().st_size > 0
    assert list(private_tmp.iterdir()) == [] and _gone(pid)


@linux
def test_a_diagnosis_stopped_after_the_figure_started_leaves_no_child_and_no_files(tmp_path, private_tmp,
                                                                                 monkeypatch):
    from conftest import VEHICLES
    from qr.effects import parse_effect_spec
    from qr.sim.synth import SynthConfig, write_synth
    from qr.stages.diagnose import run_diagnosis
    from qr.vehicle import load_vehicle

    write_synth(tmp_path / "f", load_vehicle(VEHICLES / "asctec_hummingbird.yaml"),
                [parse_effect_spec("linear_drag:kx=0.3,ky=0.3,kz=0.15")], SynthConfig(duration=40, seed=3))
    started = []
    real = BackgroundFigure.__init__

    def spy(self, draw):
        real(self, draw)
        started.append(self._pid)

    def stop_at_selection(msg):  # Ctrl-C as the selection starts: the figure is being drawn
        if msg == "selection":
            raise KeyboardInterrupt

    monkeypatch.setattr(BackgroundFigure, "__init__", spy)
    with pytest.raises(KeyboardInterrupt):
        run_diagnosis([tmp_path / "f" / "flight.csv"], tmp_path / "f" / "vehicle.yaml", tmp_path / "out",
                      track=False, log=stop_at_selection)
    assert len(started) == 1 and started[0] is not None  # a child was drawing when the run stopped
    assert list(private_tmp.iterdir()) == [] and _gone(started[0])
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
