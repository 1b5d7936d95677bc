#!/bin/bash
# {{ job_name }}: {{ summary }}
# Written by hpcves campaign --plan --slurm from its default template (hpcves/campaign/templates/slurm.sh;
# --slurm-template FILE takes yours: docs/cluster.md lists what a template may use). Set the account
# and partition, load what your site provides for MPI, parallel HDF5 and Python (README: "On a
# cluster"), then:  sbatch {{ script }}
#
# SIGTERM reaches every task {{ signal_seconds }} s before the wall time: each rank checkpoints its case
# and the job ends cleanly; while work is left (hpcves status exits 3) the script submits itself
# again, and the next job continues with --resume, bitwise as if never interrupted -- at most
# {{ max_jobs }} jobs in all (MAX_JOBS below), and not after {{ max_idle_jobs }} jobs in a row that advanced nothing.
# Memory: {{ memory_note }}
#SBATCH --job-name={{ job_name }}
#SBATCH --account=CHANGE_ME
#SBATCH --partition=CHANGE_ME
#SBATCH --ntasks={{ ranks }}
#SBATCH --cpus-per-task=1
#SBATCH --mem-per-cpu={{ mem_per_cpu }}
#SBATCH --time={{ time }}
#SBATCH --signal=TERM@{{ signal_seconds }}
#SBATCH --output={{ log }}

set -uo pipefail
# module load openmpi hdf5/parallel python      # your site's names; the same as when hpcves was installed
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1
cd {{ workdir }}
STUDY={{ study_file }}
OUT={{ output }}
HPCVES={{ hpcves }}
PYTHON={{ python }}
MAX_JOBS={{ max_jobs }}
MAX_IDLE_JOBS={{ max_idle_jobs }}

# the jobs of this chain so far, this one included (deleted once the campaign is complete)
jobs=$(( $(cat "$OUT.jobs" 2>/dev/null || echo 0) + 1 ))
echo "$jobs" > "$OUT.jobs"

# progress in a status --json: the cases in the file and their simulated time added up ("none": no file)
progress() {
    "$PYTHON" -c 'import json, sys
try:
    rows = json.load(sys.stdin)["rows"]
    print(len(rows), sum(r["t"] for r in rows if r["t"] == r["t"]))
except Exception:
    print("none")'
}
before=$("$HPCVES" status --json "$OUT" 2>/dev/null | progress)
status=0
srun --kill-on-bad-exit=0 "$HPCVES" campaign "$STUDY" --out "$OUT" --resume --quiet || status=$?
# campaign: 0 done or stopped by the signal, 1 some case failed, 2 bad input or a refused write
left=0
"$HPCVES" status --json "$OUT" > "$OUT.status.json" || left=$?
"$PYTHON" -c 'import json, sys; s = json.load(open(sys.argv[1]))
print("status:", "complete" if s.get("complete") else "work left: " + str(s.get("left")), s.get("totals", ""))' \
    "$OUT.status.json" || true
# status: 0 complete, 1 complete with failed cases, 3 work left, 2 unreadable or damaged
# a job that advanced nothing (creation that does not fit in a job, a site problem) may happen once;
# MAX_IDLE_JOBS in a row end the chain instead of resubmitting it forever
if [ "$(progress < "$OUT.status.json")" = "$before" ]; then
    idle=$(( $(cat "$OUT.idle_jobs" 2>/dev/null || echo 0) + 1 ))
    echo "$idle" > "$OUT.idle_jobs"
else
    idle=0
    rm -f "$OUT.idle_jobs"
fi
if [ "$left" -eq 3 ] && [ "$status" -le 1 ] && [ "$idle" -lt "$MAX_IDLE_JOBS" ] && [ "$jobs" -lt "$MAX_JOBS" ]; then
    echo "work left: submitting the next job ($((jobs + 1)) of at most $MAX_JOBS)"
    sbatch "$0"
elif [ "$left" -eq 3 ] && [ "$idle" -ge "$MAX_IDLE_JOBS" ]; then
    echo "work left, but $idle jobs in a row advanced nothing: not resubmitting (see the logs; delete $OUT.idle_jobs and sbatch again once the cause is fixed)" >&2
elif [ "$left" -eq 3 ] && [ "$jobs" -ge "$MAX_JOBS" ]; then
    echo "work left, but this was job $jobs of at most $MAX_JOBS (the plan's estimate was short, or cases take longer here): not resubmitting; raise MAX_JOBS in $0 or delete $OUT.jobs, then sbatch $0" >&2
elif [ "$left" -eq 3 ]; then
    echo "work left, but the campaign ended with status $status: not resubmitting; see the log above" >&2
elif [ "$left" -le 1 ]; then
    rm -f "$OUT.jobs"
fi
exit "$status"
