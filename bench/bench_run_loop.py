"""The run loop around the step -> BENCHMARKS.md (``make bench``).

A case of the reproduction's slowest study (jobs/reproduce/psi048_delta_S.toml: Delta = 0.415,
S = 1.352, N = 128, rtol = 1e-3, a sample every 0.02 and a snapshot every 0.05, run until decided)
for its first STEPS steps, on one core, two ways:

* ``run_case``: the whole run loop into an HDF5 file -- samples (diagnostics.sample), the health
  check of every step, snapshots, checkpoints, the decision every run.decision_samples samples;
* the same steps taken by the solver alone (rates, then the clock's step: the same step sequence,
  since the adaptive clock stops at every sample time either way).

The difference is what recording costs. Until 2026-12-04 the loop parsed the stored TOML at every
sample (~10 ms) instead of holding the case it runs, and wrote each snapshot by itself, one write a
field (~10 ms), instead of in blocks; this case then took 1.8 times as long (9.2 and 10.7 s against
5.6 and 5.4 s, measured by hand in turn).
"""
from __future__ import annotations

import argparse
import datetime
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_solver import machine  # noqa: E402
from report import replace_section  # noqa: E402

from hpcves.api import run_case  # noqa: E402
from hpcves.campaign.study import load_study  # noqa: E402
from hpcves.run import schedule  # noqa: E402
from hpcves.run.runner import one_thread  # noqa: E402
from hpcves.run.timestepping import Solver  # noqa: E402

STUDY = Path(__file__).resolve().parents[1] / "jobs" / "reproduce" / "psi048_delta_S.toml"
SHEAR_RATE, EXCESS_LENGTH = 1.352, 0.415
STEPS = 6000
REPEATS = 3
HEADING = "The run loop around the step"


def the_case():
    return load_study(STUDY).refine_case(0, SHEAR_RATE, EXCESS_LENGTH, "bench").case


def with_recording(case, folder: Path) -> tuple[float, float]:
    """(seconds, t reached) of run_case for STEPS steps into a new file."""
    path = folder / f"run{time.monotonic_ns()}.h5"
    start = time.perf_counter()
    outcome = run_case(case, path, max_steps=STEPS)
    seconds = time.perf_counter() - start
    path.unlink()
    return seconds, outcome.t


def solver_alone(case) -> tuple[float, float]:
    """(seconds, t reached) of the same STEPS steps without recording anything."""
    with one_thread():
        start = time.perf_counter()
        solver = Solver(case)
        clock = schedule.clock(case)
        state = solver.initial_state()
        for _ in range(STEPS):
            state, _ = clock.take_step(solver, state, solver.rates(state))
        return time.perf_counter() - start, solver.time(state)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default="BENCHMARKS.md")
    args = parser.parse_args(argv)
    start = time.time()
    case = the_case()
    runs, alone = [], []
    print(f"run loop: {REPEATS} x 2 runs of {STEPS} steps ...", file=sys.stderr)
    with tempfile.TemporaryDirectory() as folder:
        for _ in range(REPEATS):                      # in turn, so that a load change hits both
            runs.append(with_recording(case, Path(folder)))
            alone.append(solver_alone(case))
    t_run, t_alone = runs[0][1], alone[0][1]
    recorded, bare = statistics.median(s for s, _ in runs), statistics.median(s for s, _ in alone)
    run = case.run
    samples, snapshots = t_run / run.sample_interval, t_run / run.snapshot_interval
    lines = [f"## {HEADING}", "",
             f"Run {datetime.datetime.now():%Y-%m-%d %H:%M} by `bench/bench_run_loop.py` ({time.time() - start:.0f} s) "
             f"on: {machine()}.", "",
             f"A case of jobs/reproduce/psi048_delta_S.toml (Delta = {EXCESS_LENGTH}, S = {SHEAR_RATE}, "
             f"N = {case.numerics.N}, rtol = {case.numerics.rtol:g}, a sample every {run.sample_interval:g}, "
             f"a snapshot every {run.snapshot_interval:g}), its first {STEPS} steps (to t = {t_run:.4g}: "
             f"~{samples:.0f} samples, ~{snapshots:.0f} snapshots), on one core; medians of {REPEATS}.", "",
             "| run | seconds | per step (ms) |", "| --- | ---: | ---: |",
             f"| run_case: samples, health checks, snapshots, checkpoints, decisions into HDF5 | {recorded:.2f} | "
             f"{1e3 * recorded / STEPS:.3f} |",
             f"| the solver alone, the same steps (to t = {t_alone:.4g}) | {bare:.2f} | {1e3 * bare / STEPS:.3f} |", "",
             f"Recording costs **{recorded / bare - 1:.0%}** on top of the steps "
             f"({1e3 * (recorded - bare) / samples:.2f} ms a sample, snapshots included)."]
    replace_section(args.out, HEADING, "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
