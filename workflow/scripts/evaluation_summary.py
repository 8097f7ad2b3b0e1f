"""Snakemake rule `evaluation_summary`: the held-out rollouts of the flight sets in one table."""

from qr.errors import job_log
from qr.stages.evaluate_sets import summary_table

with job_log(snakemake.log[0]):
    summary_table({name: [held_out, learned] for name, held_out, learned in
                   zip(snakemake.params.names, snakemake.input.sets, snakemake.input.learned)},
                  snakemake.output.table)
