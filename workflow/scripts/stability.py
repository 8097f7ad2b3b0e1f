"""Snakemake rule `stability`: eigenvalues of M_{v,a} and closed loops -> stability.csv/.md, figures."""

from qr.errors import job_log
from qr.sim.simulation import simulate_config
from qr.stages.simulate import write_study

with job_log(snakemake.log[0]):
    out = snakemake.output
    write_study(simulate_config(snakemake.params.overrides), "stability", out.table,
                {"eigenvalues": out.eigenvalues, "divergence": out.divergence}, inputs=list(snakemake.input))
