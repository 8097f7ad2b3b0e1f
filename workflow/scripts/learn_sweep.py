"""Snakemake rule `learn_sweep`: one named sweep as a Hydra multirun on the rule's threads (joblib)."""
import os
import subprocess
import sys
from pathlib import Path

out = Path(snakemake.output[0]).parent
cmd = [sys.executable, "-m", "qr.train", "-m", f"sweep={snakemake.wildcards.sweep}",
       f"dataset={snakemake.input.dataset}", f"out={out}", f"hydra.sweep.dir={out / 'hydra'}",
       "hydra/launcher=joblib2", f"hydra.launcher.n_jobs={snakemake.threads}"]
env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
with open(snakemake.log[0], "w") as log:
    subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, env=env, check=True)
