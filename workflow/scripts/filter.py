"""Snakemake rules `filter_<set>_<k>`: a batch of one set's canonical flights -> state tables + NIS reports
(their MLflow runs: filter_summary)."""

from qr.errors import job_log
from qr.stages.filter_sets import run_batch

with job_log(snakemake.log[0]):
    run_batch(snakemake.input.flights, snakemake.input.vehicle, snakemake.output.states, snakemake.output.nis,
              snakemake.output.crossfit, snakemake.params.names, snakemake.params.overrides)
