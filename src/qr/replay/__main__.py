"""``python -m qr.replay ARGS`` = ``qr replay ARGS``; the stage itself is :mod:`qr.stages.replay`."""

from qr.cli import run_as

run_as("replay")
