"""Snakemake rules `ingest_<set>_<k>`: a batch of one set's raw logs -> canonical Parquet flights."""

from qr.errors import job_log
from qr.stages.ingest_sets import ingest_batch

with job_log(snakemake.log[0]):
    ingest_batch(snakemake.input.raw, snakemake.input.vehicle, snakemake.output.flights, fmt=snakemake.params.format)
