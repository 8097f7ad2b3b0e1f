"""Snakemake rule `stability`: eigenvalues of M_{v,a} and closed loops -> stability.csv/.md, figures."""
import sys

from qr.stages.simulate import simulate_config, write_stability

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    out = snakemake.output
    write_stability(simulate_config(snakemake.params.overrides), out.table,
                    {"eigenvalues": out.eigenvalues, "divergence": out.divergence}, inputs=list(snakemake.input))
