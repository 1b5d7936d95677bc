#!/bin/bash
# Run a campaign on SLURM and keep resubmitting until every case has finished.
#
#   sbatch jobs/slurm_campaign.sh                      # jobs/delta0194_S_psi.toml
#   sbatch --export=ALL,STUDY=jobs/psi048_delta_S.toml jobs/slurm_campaign.sh
#
# --signal=TERM@120 makes SLURM send SIGTERM to every task 120 s before the
# walltime: each rank checkpoints its case and the job ends cleanly; the next
# submission continues with --resume (finished cases are kept, running ones
# continue from their checkpoints, bitwise as if never interrupted).
#SBATCH --job-name=hpcves
#SBATCH --ntasks=512
#SBATCH --cpus-per-task=1
#SBATCH --time=12:00:00
#SBATCH --signal=TERM@120
#SBATCH --output=hpcves-%j.log

set -euo pipefail
STUDY=${STUDY:-jobs/delta0194_S_psi.toml}
HPCVES=${HPCVES:-.venv/bin/hpcves}
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1

status=0
srun --kill-on-bad-exit=0 "$HPCVES" campaign "$STUDY" --resume || status=$?
# 0: finished or stopped by the signal; 1: some case failed (see hpcves status); else: trouble
OUT=$(.venv/bin/python -c "from hpcves.campaign.study import load_study; print(load_study('$STUDY').output)")
# status exits 3 while work is left: cases to run, a search's or refinement's next stage, or a
# file whose creation the walltime cut short (the next job starts it again); 0/1: complete
left=0
"$HPCVES" status "$OUT" | tail -n 1 || left=$?
if [ "$left" -eq 3 ]; then
    if [ "$status" -le 1 ]; then
        echo "not finished: resubmitting"
        sbatch --export=ALL,STUDY="$STUDY" "$0"
    else
        echo "srun ended with status $status: not resubmitting; look at the log" >&2
    fi
fi
exit "$status"
