"""workflow/rules/scheduler.smk: one pending re-evaluation of Snakemake's scheduler at a time.

As shipped, Snakemake 9 arms another 1 s re-evaluation after every scheduling round, so each finished job
starts one more chain of rounds (benchmarks/scheduler_rounds.py: 60 jobs of 1 s, 931 rounds; 91 with this
file).  The replacement is checked without any clock: a round far in the future stands while more are asked
for; one due now releases the scheduler once and makes room for the next.
"""

import runpy
import threading
from types import SimpleNamespace

from conftest import ROOT

SMK = ROOT / "workflow" / "rules" / "scheduler.smk"


def test_the_snakefile_includes_it_first():
    first = [line for line in (ROOT / "Snakefile").read_text().splitlines() if line.startswith("include:")][0]
    assert first == 'include: "workflow/rules/scheduler.smk"'


def test_one_pending_round_at_a_time():
    ns = runpy.run_path(str(SMK))
    from snakemake.scheduling.job_scheduler import JobScheduler

    one = ns["_one_pending_round"]
    assert JobScheduler._schedule_reevalutation is one  # Snakemake's own method replaced
    sched = SimpleNamespace(_open_jobs=threading.Semaphore(0))
    one(sched, 3600.0)  # a round an hour away
    pending = sched._qr_pending_round
    assert pending.daemon  # never holds the process at its end
    for _ in range(5):  # more rounds asked for (finished jobs): the pending one stands, no second chain
        one(sched, 0.0)
    assert sched._qr_pending_round is pending
    pending.cancel()

    due = SimpleNamespace(_open_jobs=threading.Semaphore(0))
    one(due, 0.0)
    due._open_jobs.acquire()  # the round due now releases the scheduler (waits as long as it takes)...
    assert due._qr_pending_round is None  # ...having made room for the next round first
    assert not due._open_jobs.acquire(blocking=False)  # once
    one(due, 3600.0)
    assert due._qr_pending_round is not None
    due._qr_pending_round.cancel()
