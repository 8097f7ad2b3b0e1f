"""`qr --help` lists every command with an example, and the Hydra stage entry points with theirs."""

import importlib
import re

import pytest

from conftest import VEHICLES


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
    for needed in ("python -m qr.<stage>", "python -m qr.train = qr learn", "snakemake --cores 2", "make mlflow-ui"):
        assert needed in text


@pytest.mark.slow  # ~30 processes
def test_every_stage_runs_as_qr_stage_and_as_python_m(tmp_path):
    """``python -m qr.<stage> ARGS`` is ``qr <stage> ARGS`` for each of the seven stages (``python -m
    qr.train`` is ``qr learn``): the same help, the same one-line user error and exit 2; the Hydra
    stages' entry points are their stage modules; and ``qr --version``."""
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
        assert module == f"qr.stages.{stage}" and callable(importlib.import_module(module).main)
    missing = str(tmp_path / "missing.csv")
    cases = {"ingest": [missing, "--vehicle", "v.yaml", "--out", "f.csv"],
             "filter": [f"filter.flight={missing}"],
             "learn": [f"learn.dataset={tmp_path / 'missing.parquet'}"],
             "diagnose": [missing, "--vehicle", str(VEHICLES / "asctec_hummingbird.yaml"), "--out", "d"],
             "simulate": ["simulate.task=nonsense"],
             "evaluate": [missing, "--vehicle", str(VEHICLES / "asctec_hummingbird.yaml"), "--out", "e"],
             "replay": [missing, "--vehicle", str(VEHICLES / "asctec_hummingbird.yaml"), "--controller", "lee", "--out",
                        "r"]}
    for stage, args in cases.items():
        modules = [f"qr.{stage}"] + (["qr.train"] if stage == "learn" else [])
        h = run(qr, stage, "--help")
        assert h.returncode == 0 and h.stdout, (stage, h.stderr)
        if stage in HYDRA_STAGES:
            assert "== Configuration groups ==" in h.stdout
        a = run(qr, stage, *args, f"results={tmp_path}") if stage in HYDRA_STAGES else run(qr, stage, *args)
        assert a.returncode == 2 and len(a.stderr.strip().splitlines()) == 1, (stage, a.stderr)
        for m in modules:
            hm = run(sys.executable, "-m", m, "--help")
            assert hm.returncode == 0 and hm.stdout == h.stdout, (m, hm.stderr)
            b = run(sys.executable, "-m", m, *args, *([f"results={tmp_path}"] if stage in HYDRA_STAGES else []))
            assert b.returncode == 2 and b.stderr == a.stderr, (m, a.stderr, b.stderr)
