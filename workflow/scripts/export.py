"""Snakemake rule `export`: a set's extended vehicle in one simulator's format (qr export)."""
from pathlib import Path

from qr.errors import job_log
from qr.stages.export import run_export

with job_log(snakemake.log[0]) as log:
    out = Path(snakemake.output[0])
    out.parent.mkdir(parents=True, exist_ok=True)
    for path in run_export(Path(snakemake.input.diagnosis[0]) / "extended_vehicle.yaml", snakemake.wildcards.target,
                           out):
        print(path, file=log)
