"""Snakemake rule `diagnosis_summary`: the set diagnoses side by side."""

from qr.errors import job_log
from qr.stages.diagnose_sets import summary

with job_log(snakemake.log[0]):
    summary(dict(zip(snakemake.params.names, list(snakemake.input.sets) + list(snakemake.input.checks))),
            snakemake.output.table)
