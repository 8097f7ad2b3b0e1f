"""Snakemake rule `replay`: a set's held-out flights replayed under its controller with every model written for it."""
from pathlib import Path

from qr.errors import job_log
from qr.stages.replay_sets import replay_set

carried = [Path(snakemake.input.carried) / "hybrid_vehicle.yaml"] if snakemake.input.carried else []
with job_log(snakemake.log[0]):
    replay_set(snakemake.input.logs, snakemake.input.evaluation, [*carried, Path(snakemake.input.residual) /
               "hybrid_vehicle.yaml"], ["hybrid (rollout-trained, carried over)", "hybrid (rollout-trained, fine-tuned)"]
               if carried else ["hybrid (rollout-trained)"], snakemake.output[0], snakemake.params.controller,
               snakemake.params.overrides, track=f"replay:{snakemake.wildcards.set}")
