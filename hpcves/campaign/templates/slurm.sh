#!/bin/bash
# {{ job_name }}: {{ summary }}
# Written by hpcves campaign --plan --slurm from its default template (hpcves/campaign/templates/slurm.sh;
# --slurm-template FILE takes yours: docs/cluster.md lists what a template may use). Set the account
# and partition, load what your site provides for MPI, parallel HDF5 and Python (README: "On a
# cluster"), then:  sbatch {{ script }}
#
# SIGTERM reaches every task {{ signal_seconds }} s before the wall time: each rank checkpoints its case
# and the job ends cleanly. Each job first submits its successor, to start once it has ended however it
# ends (--dependency=afterany: a lost node, an out-of-memory kill, a scancel of this job alone), and
# cancels it once the campaign is complete; the next job continues with --resume, bitwise as if never
# interrupted -- at most {{ max_jobs }} jobs in all (MAX_JOBS below), and not after {{ max_idle_jobs }} jobs in a row that
# advanced nothing. To stop the whole chain: scancel --name={{ job_name }}
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
SCRIPT={{ script }}      # this script as submitted ($0 is slurmd's copy of it)
STUDY={{ study_file }}
OUT={{ output }}
HPCVES={{ hpcves }}
PYTHON={{ python }}
MAX_JOBS={{ max_jobs }}
MAX_IDLE_JOBS={{ max_idle_jobs }}

# progress in a status --json: the cases in the file and their simulated time added up ("none": no file)
progress() {
    "$PYTHON" -c 'import json, sys
try:
    rows = json.load(sys.stdin)["rows"]
    print(len(rows), sum(r["t"] for r in rows if r["t"] == r["t"]))
except Exception:
    print("none")'
}

# the jobs of this chain so far, this one included, and those in a row that found the campaign where the
# one before found it (however that one ended); the files go once the campaign is complete
jobs=$(( $(cat "$OUT.jobs" 2>/dev/null || echo 0) + 1 ))
echo "$jobs" > "$OUT.jobs"
now=$("$HPCVES" status --json "$OUT" 2>/dev/null | progress)
if [ -f "$OUT.progress_seen" ] && [ "$(cat "$OUT.progress_seen")" = "$now" ]; then
    idle=$(( $(cat "$OUT.idle_jobs" 2>/dev/null || echo 0) + 1 ))
else
    idle=0
fi
echo "$idle" > "$OUT.idle_jobs"
echo "$now" > "$OUT.progress_seen"
if [ "$idle" -ge "$MAX_IDLE_JOBS" ]; then
    echo "the last $idle jobs of this chain advanced nothing: stopping it (see their logs; delete $OUT.idle_jobs and sbatch $SCRIPT once the cause is fixed)" >&2
    exit 1
fi
next=""
if [ "$jobs" -lt "$MAX_JOBS" ]; then
    next=$(sbatch --parsable --dependency=afterany:"${SLURM_JOB_ID:?}" "$SCRIPT") || next=""
    next=${next%%;*}
fi
stop_chain() {
    if [ -n "$next" ]; then scancel "$next" || true; fi
}

status=0
srun --kill-on-bad-exit=0 "$HPCVES" campaign "$STUDY" --out "$OUT" --resume --quiet || status=$?
# campaign: 0 done or stopped by the signal, 1 some case failed, 2 bad input or a refused write
left=0
"$HPCVES" status --json "$OUT" > "$OUT.status.json" || left=$?
"$PYTHON" -c 'import json, sys; s = json.load(open(sys.argv[1]))
print("status:", "complete" if s.get("complete") else "work left: " + str(s.get("left")), s.get("totals", ""))' \
    "$OUT.status.json" || true
# status: 0 complete, 1 complete with failed cases, 3 work left, 2 unreadable or damaged
if [ "$left" -eq 3 ] && [ "$status" -le 1 ] && [ -n "$next" ]; then
    echo "work left: job $next continues (job $((jobs + 1)) of at most $MAX_JOBS)"
elif [ "$left" -eq 3 ] && [ "$status" -le 1 ]; then
    echo "work left, but this was job $jobs of at most $MAX_JOBS (the plan's estimate was short, or cases take longer here): no job follows; raise MAX_JOBS in $SCRIPT or delete $OUT.jobs, then sbatch $SCRIPT" >&2
elif [ "$left" -eq 3 ]; then
    stop_chain
    echo "work left, but the campaign ended with status $status: the chain stops here; see the log above, then sbatch $SCRIPT" >&2
elif [ "$left" -le 1 ]; then
    stop_chain
    rm -f "$OUT.jobs" "$OUT.idle_jobs" "$OUT.progress_seen"
else
    stop_chain
    echo "hpcves status could not read $OUT (exit $left): the chain stops here" >&2
fi
exit "$status"
