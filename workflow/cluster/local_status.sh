#!/usr/bin/env bash
# Status of a job of local_submit.sh, as Snakemake's generic-cluster executor wants it:
# one line, running | success | failed.  A job whose process is gone without an exit code
# (killed with SIGKILL, machine restarted) is failed.
set -uo pipefail
dir="${QR_CLUSTER_DIR:-.snakemake/local-cluster}/$1"
if [ -f "$dir/exitcode" ]; then
    if [ "$(cat "$dir/exitcode")" = "0" ]; then echo success; else echo failed; fi
elif [ -f "$dir/pid" ] && kill -0 "$(cat "$dir/pid")" 2> /dev/null \
        && [ "$(ps -o stat= -p "$(cat "$dir/pid")" | cut -c1)" != "Z" ]; then
    echo running
elif [ -f "$dir/exitcode" ]; then   # finished between the two checks
    if [ "$(cat "$dir/exitcode")" = "0" ]; then echo success; else echo failed; fi
else
    echo failed
fi
