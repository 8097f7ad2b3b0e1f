"""Snakemake rule `diagnose_set`: all flights of a set in one diagnosis (+ MLflow run)."""

from qr.errors import job_log
from qr.stages.diagnose_sets import diagnose_set

with job_log(snakemake.log[0]):
    diagnose_set(snakemake.input.flights, snakemake.input.nis, snakemake.input.vehicle, snakemake.output[0],
                 snakemake.params.overrides, estimates=snakemake.input.crossfit)
