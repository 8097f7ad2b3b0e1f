"""Snakemake rule `generalization_summary`: results/tables/generalization.csv (and .md)."""

from qr.errors import job_log
from qr.report.generalization import read_fold, read_scored, write

with job_log(snakemake.log[0]):
    scored = []
    for name, held_out, learned in zip(snakemake.params.names, snakemake.input.repeat, snakemake.input.learned):
        scored.append(read_scored(name, "repeat", None, [held_out, learned]))
        scored += [read_fold(s, d) for s, d in zip(snakemake.params.fold_sets, snakemake.input.folds)
                   if s == name]
    write(scored, snakemake.output.table, skipped=snakemake.params.skipped)
