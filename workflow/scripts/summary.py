"""Snakemake rule `summary`: per-flight and per-set tables, a figure, one MLflow run."""
import sys

from qr.stages.ingest_sets import write_ingest_summary

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    write_ingest_summary(snakemake.params.sets, snakemake.params.vehicles, snakemake.output.table,
                         snakemake.output.by_set, snakemake.output.figure)
