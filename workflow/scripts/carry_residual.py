"""Snakemake rule `carry_residual`: the first set's rollout-trained network on the carry-to set's refined model."""
import sys
from pathlib import Path

from qr.stages.learn_residual_sets import carry_residual

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    carry_residual(Path(snakemake.input.diagnosis) / "extended_vehicle.yaml",
                   Path(snakemake.input.residual) / "hybrid_vehicle.yaml", snakemake.output[0])
