"""Snakemake rule `diagnosis_summary`: the set diagnoses side by side."""
import sys

from qr.stages.diagnose_sets import summary

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    summary(dict(zip(snakemake.params.names, list(snakemake.input.sets) + list(snakemake.input.checks))),
            snakemake.output.table)
