"""torch stays on one thread through numba's first parallel call (qr.parallel.torch_one_thread).

numba's OpenMP pool, launched by its first parallel call, sets the thread count torch shares with it (one
libgomp) back to numba's.  Run in fresh interpreters (the pool is launched once per process), with numba
on 2 threads."""

import os
import subprocess
import sys

SCRIPT = """
import sys
import numpy as np
import torch
from numba import njit, prange
from qr.parallel import torch_one_thread

@njit(parallel=True)
def total(x):
    s = 0.0
    for i in prange(x.shape[0]):
        s += x[i]
    return s

before = torch.get_num_threads()  # as qr.residual_fit.train does, to restore it after (it inits torch's pool)
torch_one_thread(torch) if sys.argv[1] == "qr" else torch.set_num_threads(1)
total(np.ones(100))
print(torch.get_num_threads())
"""


def _threads_after_a_parallel_call(how: str) -> int:
    env = {**os.environ, "NUMBA_NUM_THREADS": "2"}
    env.pop("OMP_NUM_THREADS", None)
    out = subprocess.run([sys.executable, "-c", SCRIPT, how], env=env, capture_output=True, text=True, check=True)
    return int(out.stdout.split()[-1])


def test_one_thread_survives_numbas_first_parallel_call():
    assert _threads_after_a_parallel_call("plain") == 2  # the mechanism: set to 1, reset by numba's pool
    assert _threads_after_a_parallel_call("qr") == 1
