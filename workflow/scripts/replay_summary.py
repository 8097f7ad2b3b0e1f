"""Snakemake rule `replay_summary`: the sets' replays in one table."""
import sys

from qr.stages.replay_sets import summary_table

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    summary_table(dict(zip(snakemake.params.names, snakemake.input.sets)), snakemake.output.table)
