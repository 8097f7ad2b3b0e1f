"""Snakemake rule `overview`: the report's overview page from the workflow's tables and figures."""

from qr.errors import job_log
from qr.report.overview import write_overview

with job_log(snakemake.log[0]):
    write_overview(snakemake.output[0], snakemake.input.diagnosis, snakemake.input.rollout,
                   dict(zip(snakemake.params.thesis, snakemake.input.thesis)),
                   [tuple(f) for f in snakemake.params.figures], snakemake.output.fragment,
                   generalization_csv=snakemake.input.generalization, replay_csv=snakemake.input.replay)
