"""Snakemake rule `simulate`: the tracking study -> tracking.csv/.md, three figures, MLflow runs."""
import sys

from qr.stages.simulate import simulate_config, write_tracking

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    out = snakemake.output
    write_tracking(simulate_config(snakemake.params.overrides), out.table,
                   {"tracking": out.tracking, "euler": out.euler, "rmse": out.rmse}, inputs=list(snakemake.input))
