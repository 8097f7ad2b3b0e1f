"""Snakemake rule `carry_over`: the first set's extended vehicle with the payload frame's mass."""
from pathlib import Path

from qr.errors import job_log
from qr.stages.diagnose_sets import carry_over

with job_log(snakemake.log[0]):
    carry_over(Path(snakemake.input.first[0]) / "extended_vehicle.yaml", snakemake.input.base, snakemake.output[0])
