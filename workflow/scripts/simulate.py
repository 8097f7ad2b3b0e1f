"""Snakemake rule `simulate`: the tracking study -> tracking.csv/.md, three figures, MLflow runs."""
import sys

from qr.sim.simulation import simulate_config
from qr.stages.simulate import write_study

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    out = snakemake.output
    write_study(simulate_config(snakemake.params.overrides), "tracking", out.table,
                {"tracking": out.tracking, "euler": out.euler, "rmse": out.rmse}, inputs=list(snakemake.input))
