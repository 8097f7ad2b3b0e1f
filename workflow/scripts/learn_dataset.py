"""Snakemake rule `learn_dataset`: the filtered flights of one set -> one learning table."""
import sys

from qr.stages.learn_sets import build_dataset

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    build_dataset(snakemake.input.estimates, snakemake.params.flights, snakemake.input.vehicle, snakemake.output[0])
