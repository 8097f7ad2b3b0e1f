"""Snakemake rule `evaluate_learned`: the rollout-trained residuals on a set's held-out flights."""
from pathlib import Path

from qr.errors import job_log
from qr.holdout import SplitConfig
from qr.stages.evaluate_sets import evaluate_learned

carried = [Path(snakemake.input.carried) / "hybrid_vehicle.yaml"] if snakemake.input.carried else []
with job_log(snakemake.log[0]):
    evaluate_learned(snakemake.input.flights, snakemake.input.nis, snakemake.input.vehicle,
                     [*carried, Path(snakemake.input.residual) / "hybrid_vehicle.yaml"],
                     ["hybrid (rollout-trained, carried over)", "hybrid (rollout-trained, fine-tuned)"] if carried
                     else ["hybrid (rollout-trained)"], snakemake.output[0],
                     track=f"learned:{snakemake.wildcards.set}", estimates=snakemake.input.crossfit,
                     split=SplitConfig.from_dict(snakemake.params.split))
