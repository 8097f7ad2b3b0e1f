"""Snakemake rule `evaluation_summary`: the held-out rollouts of the flight sets in one table."""
import sys

from qr.stages.evaluate_sets import summary_table

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    summary_table({name: [held_out, learned] for name, held_out, learned in
                   zip(snakemake.params.names, snakemake.input.sets, snakemake.input.learned)},
                  snakemake.output.table)
