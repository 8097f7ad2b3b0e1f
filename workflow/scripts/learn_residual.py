"""Snakemake rule `learn_residual`: a residual trained through the rollout on a set's training flights."""
from pathlib import Path

from qr.errors import job_log
from qr.stages.learn_residual_sets import train_held_out

# on the training diagnosis's (refined) physical model; the carry-to set: fine-tuning the carried network
vehicle = (Path(snakemake.input.carried) / "hybrid_vehicle.yaml" if snakemake.input.carried
           else Path(snakemake.input.diagnosis) / "extended_vehicle.yaml")
with job_log(snakemake.log[0]) as log:
    train_held_out(snakemake.input.flights, vehicle, snakemake.output[0], snakemake.params.overrides,
                   reports=snakemake.input.nis, estimates=snakemake.input.crossfit, track=True,
                   log=lambda m: print(m, file=log, flush=True))
