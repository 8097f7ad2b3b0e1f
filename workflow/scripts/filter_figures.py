"""Snakemake rule `filter_figures`: filtered vs raw for one flight, like thesis Figs. 4.2-4.8."""
from pathlib import Path

from qr.errors import job_log
from qr.stages.filter_sets import figures

with job_log(snakemake.log[0]):
    figures(snakemake.input.flight[0], snakemake.input.states[0], Path(snakemake.output[0]).parent,
            snakemake.params.title, snakemake.input.vehicle)
