"""``python -m qr.ingest ARGS`` = ``qr ingest ARGS``; the stage itself is :mod:`qr.stages.ingest`."""

from qr.cli import run_as

run_as("ingest")
