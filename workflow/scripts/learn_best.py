"""Snakemake rule `learn_best`: copy each table's best model that does not leak its target (for simulation)."""

from qr.errors import job_log
from qr.stages.learn_sets import copy_best

with job_log(snakemake.log[0]):
    copy_best(snakemake.input.force[0], snakemake.output.force)
    copy_best(snakemake.input.torque[0], snakemake.output.torque)
