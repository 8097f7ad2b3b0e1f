"""Snakemake rule `generalization_fold`: one held-out split of a set, trained and scored."""

from qr.errors import job_log
from qr.holdout import Fold
from qr.stages.evaluate_sets import run_fold

with job_log(snakemake.log[0]) as log:
    run_fold(snakemake.input.flights, snakemake.input.nis, snakemake.input.vehicle, snakemake.output[0],
             Fold.from_dict(snakemake.params.fold), snakemake.params.overrides, snakemake.params.single,
             snakemake.params.residual, estimates=snakemake.input.crossfit,
             track=f"fold:{snakemake.wildcards.set}/{snakemake.wildcards.fold}",
             log=lambda m: print(m, file=log, flush=True))
