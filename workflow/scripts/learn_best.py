"""Snakemake rule `learn_best`: copy each table's best model that does not leak its target (for simulation)."""
import sys

from qr.stages.learn_sets import copy_best

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    copy_best(snakemake.input.force[0], snakemake.output.force)
    copy_best(snakemake.input.torque[0], snakemake.output.torque)
