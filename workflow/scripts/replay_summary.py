"""Snakemake rule `replay_summary`: the sets' replays in one table."""

from qr.errors import job_log
from qr.stages.replay_sets import summary_table

with job_log(snakemake.log[0]):
    summary_table(dict(zip(snakemake.params.names, snakemake.input.sets)), snakemake.output.table)
