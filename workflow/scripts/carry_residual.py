"""Snakemake rule `carry_residual`: the first set's rollout-trained network on the carry-to set's refined model."""
from pathlib import Path

from qr.errors import job_log
from qr.stages.learn_residual_sets import carry_residual

with job_log(snakemake.log[0]):
    carry_residual(Path(snakemake.input.diagnosis) / "extended_vehicle.yaml",
                   Path(snakemake.input.residual) / "hybrid_vehicle.yaml", snakemake.output[0])
