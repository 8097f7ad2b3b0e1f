#!/usr/bin/env bash
# A stand-in for a cluster's submit command (sbatch, qsub), so that Snakemake's generic-cluster
# code path (profiles/local-cluster) runs on one machine and in the test suite (tests/workflow/test_cluster.py).
#
#   local_submit.sh JOBSCRIPT   ->  prints a job id; the job runs in the background, in its own
#                                   session (like a cluster job it outlives the Snakemake that
#                                   submitted it; local_cancel.sh ends it).
# Job records: $QR_CLUSTER_DIR (default .snakemake/local-cluster)/<id>/{jobscript.sh,pid,log,exitcode}.
set -euo pipefail
jobscript="${@: -1}"
[ -f "$jobscript" ] || { echo "local_submit.sh: no job script '$jobscript'" >&2; exit 2; }
root="${QR_CLUSTER_DIR:-.snakemake/local-cluster}"
mkdir -p "$root"
dir="$(mktemp -d "$root/job.$(date +%s%N).XXXXXX")"   # ids sort by submission time
id="$(basename "$dir")"
cp "$jobscript" "$dir/jobscript.sh"          # Snakemake may delete its copy before the job starts
# local_job.py runs it in a session of its own and writes the exit code when all of it has ended
setsid python3 "$(dirname "$0")/local_job.py" "$dir" < /dev/null > /dev/null 2>&1 &
echo $! > "$dir/pid"
echo "$id"
