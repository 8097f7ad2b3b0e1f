#!/usr/bin/env bash
# Cancel jobs of local_submit.sh (Snakemake calls it with job ids when it is interrupted):
# SIGTERM to each job's whole process group, so tracked runs end KILLED (qr.tracking).
set -uo pipefail
for id in "$@"; do
    pidfile="${QR_CLUSTER_DIR:-.snakemake/local-cluster}/$id/pid"
    [ -f "$pidfile" ] && kill -TERM -- "-$(cat "$pidfile")" 2> /dev/null
done
exit 0
