"""Snakemake rule `learn_sweep`: one named sweep as a Hydra multirun on the rule's threads (joblib)."""
import os
import signal
import subprocess
import sys
from pathlib import Path

from qr.stages.sweep_callback import end_orphaned_runs

out = Path(snakemake.output[0]).parent
cmd = [sys.executable, "-m", "qr.learn", "-m", f"sweep={snakemake.wildcards.sweep}",
       f"learn.dataset={snakemake.input.dataset}", f"learn.out={out}", f"hydra.sweep.dir={out / 'hydra'}",
       "hydra/launcher=joblib2", f"hydra.launcher.n_jobs={snakemake.threads}", *snakemake.params.overrides]
env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
with open(snakemake.log[0], "w") as log:
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env)
    # SIGTERM (a cancelled cluster job) goes on to the sweep, and on Ctrl-C (which the sweep, in the
    # same process group, receives too) we wait: either way the sweep closes its MLflow runs as
    # KILLED / FAILED before this job ends, instead of being left behind.
    signal.signal(signal.SIGTERM, lambda signum, frame: proc.send_signal(signum))
    try:
        rc = proc.wait()
    except KeyboardInterrupt:
        try:
            proc.wait(timeout=120)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        end_orphaned_runs(out)  # what a process of the sweep could not end itself
        raise
    if rc != 0:
        raise subprocess.CalledProcessError(rc, cmd)
