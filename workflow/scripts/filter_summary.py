"""Snakemake rule `filter_summary`: mean NIS of every filtered flight -> one table (+ MLflow run)."""
import sys

from qr.filter import summarize

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    summarize(dict(zip(snakemake.params.names, snakemake.input.nis)), snakemake.output.table)
