"""Snakemake rule `evaluate_held_out`: diagnose the training flights, roll out on the held-out ones."""

from qr.errors import job_log
from qr.holdout import SplitConfig
from qr.stages.evaluate_sets import evaluate_held_out

with job_log(snakemake.log[0]):
    evaluate_held_out(snakemake.input.flights, snakemake.input.nis, snakemake.input.vehicle,
                      snakemake.output.diagnosis, snakemake.output.evaluation, snakemake.params.overrides,
                      snakemake.params.single, track=f"held_out:{snakemake.wildcards.set}",
                      estimates=snakemake.input.crossfit, split=SplitConfig.from_dict(snakemake.params.split))
