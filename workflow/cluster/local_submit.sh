#!/usr/bin/env bash
# A stand-in for a cluster's submit command (sbatch, qsub), so that Snakemake's generic-cluster
# code path (profiles/local-cluster) runs on one machine and in the test suite (tests/test_cluster.py).
#
#   local_submit.sh JOBSCRIPT   ->  prints a job id; the job runs in the background, in its own
#                                   session (like a cluster job it outlives the Snakemake that
#                                   submitted it; local_cancel.sh ends it).
# Job records: $QR_CLUSTER_DIR (default .snakemake/local-cluster)/<id>/{pid,exitcode,log}.
set -euo pipefail
jobscript="${@: -1}"
[ -f "$jobscript" ] || { echo "local_submit.sh: no job script '$jobscript'" >&2; exit 2; }
root="${QR_CLUSTER_DIR:-.snakemake/local-cluster}"
mkdir -p "$root"
dir="$(mktemp -d "$root/job.XXXXXXXX")"
id="$(basename "$dir")"
cp "$jobscript" "$dir/jobscript.sh"          # Snakemake may delete its copy before the job starts
# exitcode is written by a temporary + rename, so the status script never reads half of it
setsid bash -c 'bash "$1/jobscript.sh" > "$1/log" 2>&1; echo $? > "$1/exitcode.tmp"; mv "$1/exitcode.tmp" "$1/exitcode"' \
    local-job "$dir" < /dev/null > /dev/null 2>&1 &
echo $! > "$dir/pid"
echo "$id"
