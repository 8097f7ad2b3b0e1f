# One pending re-evaluation of the job scheduler at a time.
#
# Snakemake 9.27.1 (the newest on the registry) arms a timer for another scheduling round after every round
# whenever a job-rate limit is set, which it always is (--max-jobs-per-timespan, default 100/1s).  Every
# round that a finished job starts arms one more, so after n finished jobs n timer chains run side by side:
# n rounds a second, each checking the size of every ready job's inputs.  On `make reproduce` the snakemake
# process itself burned 41 % of a core that way (1851 s of CPU in 76 min), beside the two jobs on 2 cores.
# The rate limit needs one pending round at most; that is all this changes (benchmarks/scheduler_rounds.py).
import threading as _threading

try:
    from snakemake.scheduling.job_scheduler import JobScheduler as _JobScheduler
except ImportError:  # another Snakemake layout: left as it is
    _JobScheduler = None


def _one_pending_round(self, delay):
    if getattr(self, "_qr_pending_round", None) is not None:
        return

    def fire():
        self._qr_pending_round = None
        self._open_jobs.release()

    timer = _threading.Timer(delay, fire)
    timer.daemon = True  # a pending round never holds the process at its end
    self._qr_pending_round = timer
    timer.start()


if _JobScheduler is not None and hasattr(_JobScheduler, "_schedule_reevalutation"):
    _JobScheduler._schedule_reevalutation = _one_pending_round
