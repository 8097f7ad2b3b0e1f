"""Snakemake rules `ingest_<set>_<k>`: a batch of one set's raw logs -> canonical Parquet flights."""
import sys

from qr.stages.ingest_sets import ingest_batch

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    ingest_batch(snakemake.input.raw, snakemake.input.vehicle, snakemake.output.flights, fmt=snakemake.params.format)
