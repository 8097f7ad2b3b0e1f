"""Snakemake rule `summary`: per-flight and per-set tables, a figure, one MLflow run."""

from qr.errors import job_log
from qr.stages.ingest_sets import write_ingest_summary

with job_log(snakemake.log[0]):
    write_ingest_summary(snakemake.params.sets, snakemake.params.vehicles, snakemake.output.table,
                         snakemake.output.by_set, snakemake.output.figure)
