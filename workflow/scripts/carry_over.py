"""Snakemake rule `carry_over`: the first set's extended vehicle with the payload frame's mass."""
import sys
from pathlib import Path

from qr.stages.diagnose_sets import carry_over

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    carry_over(Path(snakemake.input.first[0]) / "extended_vehicle.yaml", snakemake.input.base, snakemake.output[0])
