"""Snakemake rule `diagnose_set`: all flights of a set in one diagnosis (+ MLflow run)."""
import sys

from qr.stages.diagnose_sets import diagnose_set

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    diagnose_set(snakemake.input.flights, snakemake.input.nis, snakemake.input.vehicle, snakemake.output[0],
                 snakemake.params.overrides, estimates=snakemake.input.crossfit)
