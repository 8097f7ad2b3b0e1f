"""Snakemake rule `filter_summary`: an MLflow run per filtered flight, and the NIS table (+ its run)."""

from qr.errors import job_log
from qr.stages.filter_sets import summarize, track_runs

with job_log(snakemake.log[0]):
    track_runs(snakemake.params.names, snakemake.input.flights, snakemake.input.vehicles, snakemake.input.states,
               snakemake.input.nis)
    summarize(dict(zip(snakemake.params.names, snakemake.input.nis)), snakemake.output.table)
