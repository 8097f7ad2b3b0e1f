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
    for module in re.findall(r"python -m (qr\.\w+)", text):
        m = importlib.import_module(module)
        assert hasattr(m, "main") or hasattr(m, "_main"), module
        assert re.search(rf"^\s+python -m {re.escape(module)}\s+\S", text, re.M), f"{module} has no description"
    for needed in ("qr.filter", "qr.train", "qr.simulate", "snakemake --cores 2", "make mlflow-ui"):
        assert needed in text
