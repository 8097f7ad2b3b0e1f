"""``python -m qr.diagnose ARGS`` = ``qr diagnose ARGS``; the stage itself is :mod:`qr.stages.diagnose`."""

from qr.cli import run_as

run_as("diagnose")
