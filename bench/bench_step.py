"""CPU per time step of the solver, this tree against another -> BENCHMARKS.md ("Throughput").

Issue #41 asks for the per-step CPU at N = 64 and 128 against the commit it started from, measured in
one run. Each measurement is a child process importing hpcves from one tree (PYTHONPATH; run from
outside both): the solver of psi_bar = 0.3, S = 80 (and psi_bar = 0, S = 10) at a fixed dt = 1e-3,
40 steps past the start-up, then blocks of steps timed with ``time.thread_time`` (the CPU of its one
thread; BLAS held to one thread). The trees alternate round by round, so a machine that slows down
slows both; the table gives the median over rounds of each tree's median block, and their ratio.

    git worktree add /tmp/base <commit>
    python bench/bench_step.py --base /tmp/base --N 64 128 256 512 --rounds 5
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]

#: (label, Physics keywords) of the cases timed
CASES = {"two-phase": dict(psi_bar=0.3, shear_rate=80.0), "homogeneous": dict(psi_bar=0.0, shear_rate=10.0)}

#: what a child runs: only the solver's public calls, so the same text times any tree
CHILD = """
import json, statistics, sys, time
from hpcves.run.runner import one_thread
one_thread()
from hpcves.model.params import Case, Numerics, Physics, RunControl
try:
    from hpcves.solver.timestepping import Solver
except ImportError:                               # a tree from before the solver/ layer
    from hpcves.run.timestepping import Solver
N, physics, blocks, seconds = json.loads(sys.argv[1])
solver = Solver(Case(Physics(**physics), Numerics(N=N, dt=1e-3), RunControl(t_end=1e3)))
state = solver.initial_state()
for _ in range(40):
    state, _, _ = solver.step(state)
steps, spent = 10, 0.0
while spent < seconds / 4:                       # steps a block, so that a block takes ~seconds
    start = time.thread_time()
    for _ in range(steps):
        state, _, _ = solver.step(state)
    spent = time.thread_time() - start
    steps *= 2
steps = max(10, int(steps / 2 * seconds / max(spent, 1e-9)))
times = []
for _ in range(blocks):
    start = time.thread_time()
    for _ in range(steps):
        state, _, _ = solver.step(state)
    times.append((time.thread_time() - start) / steps)
print(json.dumps({"ms": 1e3 * statistics.median(times), "steps": steps}))
"""


def measure(tree: Path, N: int, physics: dict, blocks: int = 5, seconds: float = 0.2) -> float:
    """Median milliseconds of CPU a step of ``tree``'s solver (a child process)."""
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    with tempfile.TemporaryDirectory() as outside:            # not the cwd of either tree
        out = subprocess.run([sys.executable, "-c", CHILD, json.dumps([N, physics, blocks, seconds])],
                             capture_output=True, text=True, env=env, cwd=outside, timeout=1800)
    if out.returncode != 0:
        raise SystemExit(f"{tree}, N = {N}: {out.stderr[-2000:]}")
    return json.loads(out.stdout.splitlines()[-1])["ms"]


def commit_of(tree: Path) -> str:
    out = subprocess.run(["git", "-C", str(tree), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    dirty = subprocess.run(["git", "-C", str(tree), "status", "--porcelain", "--untracked-files=no"],
                           capture_output=True, text=True).stdout.strip()
    return (out.stdout.strip() or "?") + ("+" if dirty else "")


def compare(base: Path, new: Path, sizes, cases, rounds: int, blocks: int = 5, seconds: float = 0.2) -> list[dict]:
    """One row per case and N: medians over ``rounds`` of each tree's median block, alternating."""
    rows = []
    for label in cases:
        for N in sizes:
            found = {"base": [], "new": []}
            for _ in range(rounds):
                for which, tree in (("base", base), ("new", new)):
                    found[which].append(measure(tree, N, CASES[label], blocks, seconds))
            b, n = statistics.median(found["base"]), statistics.median(found["new"])
            rows.append({"case": label, "N": N, "base_ms": b, "new_ms": n, "ratio": b / n,
                         "base_spread": (min(found["base"]), max(found["base"])),
                         "new_spread": (min(found["new"]), max(found["new"]))})
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", type=Path, required=True, help="the tree to compare against (a git worktree)")
    parser.add_argument("--new", type=Path, default=HERE, help="the tree measured (default: this one)")
    parser.add_argument("--N", type=int, nargs="+", default=[64, 128, 256, 512])
    parser.add_argument("--cases", nargs="+", default=["two-phase"], choices=sorted(CASES))
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args(argv)
    rows = compare(args.base.resolve(), args.new.resolve(), args.N, args.cases, args.rounds)
    print(f"{os.uname().nodename}, {time.strftime('%Y-%m-%d %H:%M')}, base {commit_of(args.base)}, "
          f"new {commit_of(args.new)}, {args.rounds} rounds alternating, ms of CPU a step (fixed dt = 1e-3)\n")
    print("| case | N | base ms / step (min-max) | new ms / step (min-max) | base / new |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for r in rows:
        print(f"| {r['case']} | {r['N']} | {r['base_ms']:.3f} ({r['base_spread'][0]:.3f}-{r['base_spread'][1]:.3f}) | "
              f"{r['new_ms']:.3f} ({r['new_spread'][0]:.3f}-{r['new_spread'][1]:.3f}) | {r['ratio']:.2f}x |")
    return rows


if __name__ == "__main__":
    main()
