"""A SLURM batch script for a study, sized from its plan (``hpcves campaign --plan --slurm``).

The script runs ``hpcves campaign --resume`` under srun, asks ``hpcves status --json``
what is left, and submits itself again while work is left (status exit 3) -- a
study larger than one job's wall time goes on in the next job, from the
checkpoints -- unless MAX_IDLE_JOBS jobs in a row advanced nothing. Every path in it is absolute, so it runs from any directory.
"""
from __future__ import annotations

import math
import shlex
from dataclasses import dataclass
from pathlib import Path

#: seconds before the wall time at which SLURM sends SIGTERM: the campaign's stop_timeout
#: (every rank checkpoints) plus this margin for the status call and the resubmission
SIGNAL_MARGIN = 60
#: jobs in a row that advance nothing (no case added, no simulated time) before the chain stops
MAX_IDLE_JOBS = 2


@dataclass(frozen=True)
class JobSize:
    ranks: int
    wall_seconds: float          # what the job asks for (#SBATCH --time)


def job_time(seconds: float) -> str:
    """SLURM's --time: D-HH:MM:SS."""
    seconds = int(math.ceil(seconds))
    days, rest = divmod(seconds, 86400)
    hours, rest = divmod(rest, 3600)
    minutes, seconds = divmod(rest, 60)
    return (f"{days}-" if days else "") + f"{hours:02d}:{minutes:02d}:{seconds:02d}"


def slurm_script(*, script: Path, study_name: str, study_file: Path, output: Path, size: JobSize, hpcves: Path,
                 python: Path, workdir: Path, stop_timeout: float, summary: str) -> str:
    """The batch script's text (paths are made absolute here)."""
    q = lambda p: shlex.quote(str(Path(p).absolute()))       # not resolve(): a venv's python is a link
    signal = int(math.ceil(stop_timeout)) + SIGNAL_MARGIN
    return f"""#!/bin/bash
# {study_name}: {summary}
# Written by hpcves campaign --plan --slurm. Set the account and partition, load what your site
# provides for MPI, parallel HDF5 and Python (README: "On a cluster"), then:  sbatch {q(script)}
#
# SIGTERM reaches every task {signal} s before the wall time: each rank checkpoints its case and
# the job ends cleanly; while work is left (hpcves status exits 3) the script submits itself
# again, and the next job continues with --resume, bitwise as if never interrupted.
#SBATCH --job-name=hpcves-{study_name}
#SBATCH --account=CHANGE_ME
#SBATCH --partition=CHANGE_ME
#SBATCH --ntasks={size.ranks}
#SBATCH --cpus-per-task=1
#SBATCH --time={job_time(size.wall_seconds)}
#SBATCH --signal=TERM@{signal}
#SBATCH --output=hpcves-{study_name}-%j.log

set -uo pipefail
# module load openmpi hdf5/parallel python      # your site's names; the same as when hpcves was installed
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1
cd {q(workdir)}
STUDY={q(study_file)}
OUT={q(output)}
HPCVES={q(hpcves)}
PYTHON={q(python)}

# progress in a status --json: the cases in the file and their simulated time added up ("none": no file)
progress() {{
    "$PYTHON" -c 'import json, sys
try:
    rows = json.load(sys.stdin)["rows"]
    print(len(rows), sum(r["t"] for r in rows if r["t"] == r["t"]))
except Exception:
    print("none")'
}}
before=$("$HPCVES" status --json "$OUT" 2>/dev/null | progress)
status=0
srun --kill-on-bad-exit=0 "$HPCVES" campaign "$STUDY" --out "$OUT" --resume --quiet || status=$?
# campaign: 0 done or stopped by the signal, 1 some case failed, 2 bad input or a refused write
left=0
"$HPCVES" status --json "$OUT" > "$OUT.status.json" || left=$?
"$PYTHON" -c 'import json, sys; s = json.load(open(sys.argv[1]))
print("status:", "complete" if s.get("complete") else "work left: " + str(s.get("left")), s.get("totals", ""))' \\
    "$OUT.status.json" || true
# status: 0 complete, 1 complete with failed cases, 3 work left, 2 unreadable or damaged
# a job that advanced nothing (creation that does not fit in a job, a site problem) may happen once;
# {MAX_IDLE_JOBS} in a row end the chain instead of resubmitting it forever
if [ "$(progress < "$OUT.status.json")" = "$before" ]; then
    idle=$(( $(cat "$OUT.idle_jobs" 2>/dev/null || echo 0) + 1 ))
    echo "$idle" > "$OUT.idle_jobs"
else
    idle=0
    rm -f "$OUT.idle_jobs"
fi
if [ "$left" -eq 3 ] && [ "$status" -le 1 ] && [ "$idle" -lt {MAX_IDLE_JOBS} ]; then
    echo "work left: submitting the next job"
    sbatch "$0"
elif [ "$left" -eq 3 ] && [ "$idle" -ge {MAX_IDLE_JOBS} ]; then
    echo "work left, but $idle jobs in a row advanced nothing: not resubmitting (see the logs; delete $OUT.idle_jobs and sbatch again once the cause is fixed)" >&2
elif [ "$left" -eq 3 ]; then
    echo "work left, but the campaign ended with status $status: not resubmitting; see the log above" >&2
fi
exit "$status"
"""
