"""Threads for independent compiled work (the filters of one flight, its cross-fitting halves).

The compiled kernels release the GIL (``nogil``), so threads run them in parallel without copying
the data to other processes.  One knob for all of qr's parallelism: numba's thread count
(``NUMBA_NUM_THREADS``, default the cores), which the rollout's ``prange`` uses too.  Results do
not depend on it: every task computes the same numbers alone or beside others.  BLAS keeps one
thread while qr runs its own (:func:`blas_one_thread`): two pools on the same cores fight (the
1-hour diagnosis took 62 s with OpenBLAS's threads, 57 s without).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Callable, Iterable, TypeVar

T = TypeVar("T")
R = TypeVar("R")


def workers() -> int:
    import numba

    return max(1, int(numba.get_num_threads()))


def torch_one_thread(torch) -> None:
    """Set torch to one thread, for good.  numba's first parallel call launches its OpenMP pool, which sets
    the thread count torch shares with it (one libgomp) back to numba's: torch then trained its small
    nets on 2 threads, 5x the wall on loaded cores (docs/learn.md, "Batch size, and the threads").  The
    pool is launched first (:func:`workers` does), so a later parallel call leaves the count alone."""
    workers()
    torch.set_num_threads(1)


def thread_map(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[fn(x) for x in items]``, on up to :func:`workers` threads, in order; the first error raised."""
    items = list(items)
    n = min(workers(), len(items))
    if n <= 1:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(n) as ex:
        return list(ex.map(fn, items))


@contextmanager
def blas_one_thread():
    """numpy's BLAS (OpenBLAS, MKL) on one thread inside the block, whatever it was before."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield
