#!/usr/bin/env python3
"""One job of local_submit.sh, run in a session of its own: run the job script, then record its exit code.

Like a cluster's job step, the job ends when its script has ended AND every other process of the
job has gone: what is still running then gets SIGTERM, and SIGKILL after a grace period.  Only
then is ``exitcode`` written (a temporary + rename), so local_status.sh never reports a job as
finished while a process of it can still write.  A cancel (local_cancel.sh: SIGTERM to the whole
session) reaches the job's processes; this one waits for them and records the exit code.
"""
import os
import signal
import subprocess
import sys
import time

GRACE_S = 30


def others(sid: int) -> list[int]:
    """Live processes of session ``sid`` other than this one (zombies do not count)."""
    out = []
    for p in os.listdir("/proc"):
        if not p.isdigit() or int(p) == os.getpid():
            continue
        try:
            with open(f"/proc/{p}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        if int(fields[3]) == sid and fields[0] not in ("Z", "X"):
            out.append(int(p))
    return out


def main(job_dir: str) -> None:
    sid = os.getsid(0)
    signal.signal(signal.SIGTERM, lambda signum, frame: None)  # the job's processes get it; we wait for them
    with open(os.path.join(job_dir, "log"), "w") as log:
        rc = subprocess.call(["bash", os.path.join(job_dir, "jobscript.sh")], stdout=log, stderr=subprocess.STDOUT,
                             stdin=subprocess.DEVNULL)
    for sig, wait_s in ((signal.SIGTERM, GRACE_S), (signal.SIGKILL, GRACE_S)):
        deadline = time.monotonic() + wait_s
        while others(sid) and time.monotonic() < deadline:
            time.sleep(0.2)
        left = others(sid)
        if not left:
            break
        for pid in left:
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                pass
    tmp = os.path.join(job_dir, "exitcode.tmp")
    with open(tmp, "w") as f:
        f.write(f"{rc}\n")
    os.replace(tmp, os.path.join(job_dir, "exitcode"))


if __name__ == "__main__":
    main(sys.argv[1])
