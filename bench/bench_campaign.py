"""Campaign benchmarks -> the "Campaigns" section of BENCHMARKS.md (``make bench``).

1. Throughput of ``mpirun -n 2`` against ``mpirun -n 1`` on 8 equal cases
   (target >= 1.9x): wall time of the whole command and of the campaign itself
   (from opening the file to closing it), alternating n = 1 and n = 2 runs,
   medians.
   The same at n = 2 with ``--io relay`` (rank 0 writes for everyone, the
   fallback when h5py has no MPI).
2. Checkpoint overhead: the time every rank spends writing checkpoints (the
   two-slot protocol with its validity marker, under parallel HDF5 for n = 2),
   as a fraction of the campaign's wall time (target <= 1 %).

Run as ``python bench/bench_campaign.py --out BENCHMARKS.md``; it starts the
MPI jobs itself (``--job`` is the part that runs under mpirun).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from report import replace_section

STUDY = """
[campaign]
name = "bench"
output = "{output}"
t_end = {t_end}
[physics]
shear_rate = 80.0
psi_bar = 0.3
[numerics]
N = 64
dt = 1e-3
[run]
sample_interval = 0.005
snapshot_interval = 0.05
checkpoint_interval = 0.5
[sweep]
B2 = {values}
"""
N_CASES = 8
CONFIGS = {"1": (1, "auto"), "2": (2, "mpio"), "2 relay": (2, "relay")}     # label -> (ranks, io)
ACCESS = {"auto": "serial", "mpio": "mpio", "relay": "relay"}


def job(study_path: str, io: str) -> None:
    """Under mpirun: run the study, time the checkpoint writes on every rank, print JSON on rank 0."""
    from mpi4py import MPI

    from hpcves.campaign.driver import run_campaign
    from hpcves.campaign.study import load_study
    from hpcves.run import store as checkpoint

    spent = [0.0, 0]
    original = checkpoint.CaseStore.write_checkpoint

    def timed(self, state, flush):
        t0 = time.perf_counter()
        original(self, state, flush)
        spent[0] += time.perf_counter() - t0
        spent[1] += 1

    checkpoint.CaseStore.write_checkpoint = timed
    comm = MPI.COMM_WORLD
    size = comm.Get_size()
    study = load_study(study_path)
    t0 = time.perf_counter()
    summary = run_campaign(study, study.output, comm if size > 1 else None, overwrite=True, io=io)
    wall = time.perf_counter() - t0
    per_rank = comm.gather((spent[0], spent[1], wall), root=0)
    if comm.Get_rank() == 0:
        assert summary.counts["finished"] == N_CASES, summary.counts
        print("RESULT " + json.dumps({"wall": wall, "checkpoint_seconds": [r[0] for r in per_rank],
                                      "checkpoints": [r[1] for r in per_rank],
                                      "rank_walls": [r[2] for r in per_rank]}))


def mpi_env() -> dict:
    env = dict(os.environ)
    env.update(OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", OMPI_MCA_pml="ob1", OMPI_MCA_btl="self,vader",
               OMPI_MCA_btl_vader_single_copy_mechanism="none")
    return env


def launch(n: int, io: str, study_path: Path) -> dict:
    t0 = time.perf_counter()
    result = subprocess.run(["mpirun", "-n", str(n), sys.executable, __file__, "--job", str(study_path),
                             "--io", io],
                            capture_output=True, text=True, env=mpi_env())
    command_wall = time.perf_counter() - t0
    if result.returncode != 0:
        raise SystemExit(f"mpirun -n {n} failed:\n{result.stderr}")
    data = json.loads(re.search(r"^RESULT (.*)$", result.stdout, re.M).group(1))
    data["command_wall"] = command_wall
    return data


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default="BENCHMARKS.md")
    parser.add_argument("--t-end", type=float, default=6.0, help="simulated time per case")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--job", help=argparse.SUPPRESS)
    parser.add_argument("--io", default="auto", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.job:
        return job(args.job, args.io)

    started = time.perf_counter()
    tmp = Path(tempfile.mkdtemp(prefix="hpcves-bench-"))
    try:
        study = tmp / "bench.toml"
        # 8 equal-cost cases (B2 varies a little so that they are 8 distinct cases)
        values = [round(0.1 + 0.001 * i, 3) for i in range(N_CASES)]
        study.write_text(STUDY.format(output=tmp / "bench.h5", t_end=args.t_end, values=values))
        runs = {label: [] for label in CONFIGS}
        for _ in range(args.repeats):
            for label, (n, io) in CONFIGS.items():
                runs[label].append(launch(n, io, study))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    def med(label, key):
        return statistics.median(r[key] for r in runs[label])

    lines = ["## Campaigns", "",
             f"Run {time.strftime('%Y-%m-%d %H:%M')} by `make bench` ({time.perf_counter() - started:.0f} s), "
             "same machine as above.", "",
             f"{N_CASES} equal cases (N = 64, dt = 1e-3, t_end = {args.t_end:g}, psi_bar = 0.3, S = 80, "
             "checkpoint every 0.5, samples every 0.005), "
             f"{args.repeats} runs of each configuration, in turn; medians. `relay` is the file access "
             "used when h5py has no MPI: rank 0 writes the other ranks' cases for them.", "",
             "| ranks | file access | command wall s (mpirun) | campaign wall s | speed-up (campaign) | "
             "speed-up (command) |",
             "| ---: | --- | ---: | ---: | ---: | ---: |"]
    for label, (n, io) in CONFIGS.items():
        lines.append(f"| {n} | {ACCESS[io]} | {med(label, 'command_wall'):.2f} | {med(label, 'wall'):.2f} | "
                     f"{med('1', 'wall') / med(label, 'wall'):.2f}x | "
                     f"{med('1', 'command_wall') / med(label, 'command_wall'):.2f}x |")
    speedup = med("1", "wall") / med("2", "wall")
    relay = med("1", "wall") / med("2 relay", "wall")
    lines += ["", f"Throughput of -n 2 against -n 1: **{speedup:.2f}x** (target >= 1.9x: "
              f"{'met' if speedup >= 1.9 else 'not met'}); through rank 0 (relay): {relay:.2f}x.", "",
              "Checkpoint overhead: time inside `CaseStore.write_checkpoint` (two-slot protocol, validity "
              "marker last; with h5py flushes at n = 1 and under relay, where rank 0 writes every "
              "checkpoint) over the campaign's wall time, summed over ranks.", "",
              "| ranks | file access | checkpoints written | seconds writing them | share of wall time |",
              "| ---: | --- | ---: | ---: | ---: |"]
    worst = 0.0
    for label, (n, io) in CONFIGS.items():
        shares = [sum(r["checkpoint_seconds"]) / (n * r["wall"]) for r in runs[label]]
        seconds = [sum(r["checkpoint_seconds"]) for r in runs[label]]
        count = runs[label][0]["checkpoints"]
        worst = max(worst, statistics.median(shares))
        lines.append(f"| {n} | {ACCESS[io]} | {sum(count)} | {statistics.median(seconds):.4f} | "
                     f"{100 * statistics.median(shares):.3f} % |")
    lines += ["", f"Checkpoint overhead: **{100 * worst:.2f} %** of wall time (target <= 1 %: "
              f"{'met' if worst <= 0.01 else 'not met'}).", ""]
    section = "\n".join(lines)

    replace_section(args.out, "Campaigns", section)
    print(section)


if __name__ == "__main__":
    main()
