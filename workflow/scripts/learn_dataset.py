"""Snakemake rule `learn_dataset`: the filtered flights of one set -> one learning table."""

from qr.errors import job_log
from qr.stages.learn_sets import build_dataset

with job_log(snakemake.log[0]):
    build_dataset(snakemake.input.estimates, snakemake.params.flights, snakemake.input.vehicle, snakemake.output[0])
