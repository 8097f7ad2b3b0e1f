"""Snakemake rule `diagnose_each`: one diagnosis per flight of a set, and their table."""

from qr.errors import job_log
from qr.stages.diagnose_sets import diagnose_each

with job_log(snakemake.log[0]):
    diagnose_each(snakemake.input.flights, snakemake.input.nis, snakemake.input.vehicle,
                  snakemake.output.flights, snakemake.output.table, snakemake.params.overrides,
                  estimates=snakemake.input.crossfit)
