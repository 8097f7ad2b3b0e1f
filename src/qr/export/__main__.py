"""``python -m qr.export ARGS`` = ``qr export ARGS``; the stage itself is :mod:`qr.stages.export`."""

from qr.cli import run_as

run_as("export")
