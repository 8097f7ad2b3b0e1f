"""Snakemake rule `filter`: one canonical flight -> state table + NIS report (MLflow run: filter_summary)."""
import sys

from qr.stages.filter import run_with_overrides

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    run_with_overrides(snakemake.input.flight, snakemake.input.vehicle, snakemake.output.states,
                       snakemake.output.nis, snakemake.params.overrides, snakemake.params.name, track=False,
                       crossfit_out=snakemake.output.crossfit)
