"""Snakemake rule `diagnose_each`: one diagnosis per flight of a set, and their table."""
import sys

from qr.stages.diagnose_sets import diagnose_each

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    diagnose_each(snakemake.input.flights, snakemake.input.nis, snakemake.input.vehicle,
                  snakemake.output.flights, snakemake.output.table, snakemake.params.overrides,
                  estimates=snakemake.input.crossfit)
