"""Snakemake rule `filter_summary`: an MLflow run per filtered flight, and the NIS table (+ its run)."""
import sys

from qr.stages.filter_sets import summarize, track_runs

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    track_runs(snakemake.params.names, snakemake.input.flights, snakemake.input.vehicles, snakemake.input.states,
               snakemake.input.nis)
    summarize(dict(zip(snakemake.params.names, snakemake.input.nis)), snakemake.output.table)
