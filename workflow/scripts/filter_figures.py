"""Snakemake rule `filter_figures`: filtered vs raw for one flight, like thesis Figs. 4.2-4.8."""
import sys
from pathlib import Path

from qr.stages.filter_sets import figures

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    figures(snakemake.input.flight[0], snakemake.input.states[0], Path(snakemake.output[0]).parent,
            snakemake.params.title, snakemake.input.vehicle)
