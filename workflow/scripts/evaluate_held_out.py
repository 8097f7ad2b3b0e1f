"""Snakemake rule `evaluate_held_out`: diagnose the training flights, roll out on the held-out ones."""
import sys

from qr.holdout import SplitConfig
from qr.stages.evaluate_sets import evaluate_held_out

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    evaluate_held_out(snakemake.input.flights, snakemake.input.nis, snakemake.input.vehicle,
                      snakemake.output.diagnosis, snakemake.output.evaluation, snakemake.params.overrides,
                      snakemake.params.single, track=f"held_out:{snakemake.wildcards.set}",
                      estimates=snakemake.input.crossfit, split=SplitConfig.from_dict(snakemake.params.split))
