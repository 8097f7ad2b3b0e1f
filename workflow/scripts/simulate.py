"""Snakemake rule `simulate`: the tracking study -> tracking.csv/.md, three figures, MLflow runs."""

from qr.errors import job_log
from qr.sim.simulation import simulate_config
from qr.stages.simulate import write_study

with job_log(snakemake.log[0]):
    out = snakemake.output
    write_study(simulate_config(snakemake.params.overrides), "tracking", out.table,
                {"tracking": out.tracking, "euler": out.euler, "rmse": out.rmse}, inputs=list(snakemake.input))
