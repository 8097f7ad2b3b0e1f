"""Snakemake rule `ingest`: one raw log -> canonical Parquet flight."""
import sys

from qr.stages.ingest import ingest
from qr.vehicle import load_vehicle

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    vehicle = load_vehicle(snakemake.input.vehicle)
    ingest(snakemake.input.raw, vehicle, snakemake.output[0], fmt=snakemake.params.format)
