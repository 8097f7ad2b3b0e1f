"""`qr --help` lists every command with an example, and the Hydra stage entry points with theirs."""

import importlib
import re

import pytest


def test_help_lists_every_command_with_an_example(capsys):
    from qr.cli import _parser, main

    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    text = capsys.readouterr().out
    parser = _parser()
    commands = [a for a in parser._subparsers._group_actions[0].choices]
    assert commands
    for cmd in commands:
        assert re.search(rf"^\s+{cmd}\s+\S", text, re.M), f"{cmd} has no one-line description"
        assert re.search(rf"^\s+qr {cmd} ", text, re.M), f"{cmd} has no example"
    for needed in ("python -m qr.filter", "qr.train", "qr.simulate", "snakemake --cores 2", "make mlflow-ui"):
        assert needed in text


def test_the_hydra_stages_run_through_qr_as_through_python_m(tmp_path):
    """``qr filter|learn|simulate ARGS`` is ``python -m qr.filter|train|simulate ARGS``: the same Hydra
    entry point (help, overrides, a user error as one line and exit 2), and ``qr --version``."""
    import subprocess
    import sys
    from pathlib import Path

    from qr import __version__
    from qr.cli import HYDRA_STAGES

    qr = str(Path(sys.executable).with_name("qr"))
    run = lambda *a: subprocess.run([*a], capture_output=True, text=True, cwd=tmp_path)  # noqa: E731
    v = run(qr, "--version")
    assert v.returncode == 0 and v.stdout.strip() == f"qr {__version__}"
    for stage, (module, _) in HYDRA_STAGES.items():
        assert callable(importlib.import_module(module).main)
        h = run(qr, stage, "--help")
        assert h.returncode == 0 and "== Configuration groups ==" in h.stdout, h.stderr
    cases = {"filter": ["filter.flight=missing.csv"], "simulate": ["sim.task=nonsense"]}
    for stage, args in cases.items():
        a, b = run(qr, stage, *args, f"results={tmp_path}"), \
            run(sys.executable, "-m", HYDRA_STAGES[stage][0], *args, f"results={tmp_path}")
        assert a.returncode == b.returncode == 2, (a.stderr, b.stderr)
        assert a.stderr == b.stderr and len(a.stderr.strip().splitlines()) == 1, a.stderr
