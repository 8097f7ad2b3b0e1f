"""Snakemake rule `learn_tables`: sweep directories -> thesis Tables 3.1, 3.2, 4.2, 4.3 and the GPR grid."""

from qr.errors import job_log
from qr.report.learning import write_learning_tables

with job_log(snakemake.log[0]):
    tables = {k: v for k, v in snakemake.output.items() if not k.endswith("_md")}
    write_learning_tables(snakemake.params.sweeps, tables)
