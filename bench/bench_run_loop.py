"""The run loop around the step -> BENCHMARKS.md (``make bench``).

A case of the reproduction's slowest study (jobs/reproduce/psi048_delta_S.toml: Delta = 0.415,
S = 1.352, rtol = 1e-3, a sample every 0.02 and a snapshot every 0.05, run until decided) on N = 96
held (the study's N adapts, and this case grows from 64 to 96 at t = 32.5: the solver alone would
not follow), on one core, two ways:

* its first STEPS steps by ``run_case`` -- the whole run loop into an HDF5 file: samples
  (diagnostics.sample), the health check of every step, snapshots, checkpoints, the decision every
  run.decision_samples samples -- against the same steps taken by the solver alone (rates, then the
  clock's step: the same step sequence, since the adaptive clock stops at every sample time either
  way), CPU seconds of the process, in turn; each repeat's own ratio, then their median;
* in place (:func:`where_it_goes`): runs of STEPS and of 2 STEPS steps with each part of the loop
  timed where it runs, against the steps of the same run. The difference of the two lengths is
  what a long run pays per step; the first way cannot give it (the difference of two differences of
  noisy seconds: 17 % to 51 % in runs of the same tree). In place a part costs more than alone (the
  steps between evict its data from the caches: a snapshot 5.5 us alone, ~20 in the loop).

Until 2026-12-04 the loop parsed the stored TOML at every
sample (~10 ms) instead of holding the case it runs, and wrote each snapshot by itself, one write a
field (~10 ms), instead of in blocks; this case then took 1.8 times as long (9.2 and 10.7 s against
5.6 and 5.4 s, measured by hand in turn).
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_solver import machine  # noqa: E402
from hpcves.api import run_case  # noqa: E402
from hpcves.campaign.study import load_study  # noqa: E402
from hpcves.run import schedule  # noqa: E402
from hpcves.run.runner import one_thread  # noqa: E402
from hpcves.solver.timestepping import Solver  # noqa: E402
from report import replace_section  # noqa: E402

STUDY = Path(__file__).resolve().parents[1] / "jobs" / "reproduce" / "psi048_delta_S.toml"
SHEAR_RATE, EXCESS_LENGTH = 1.352, 0.415
STEPS = 6000
REPEATS = 7
REPEATS_IN_PLACE = 3
HEADING = "The run loop around the step"


#: the grid the bench holds: the study's N adapts (64 to 512) and this case grows to 96 at t = 32.5;
#: the solver alone would stay on its start's grid, so both take the steps of one fixed N
GRID = 96


def the_case():
    case = load_study(STUDY).refine_case(0, SHEAR_RATE, EXCESS_LENGTH, "bench").case
    return dataclasses.replace(case, numerics=dataclasses.replace(case.numerics, N=GRID, N_max=0))


def with_recording(case, folder: Path, steps: int = STEPS) -> tuple[float, float]:
    """(seconds, t reached) of run_case for ``steps`` steps into a new file."""
    path = folder / f"run{time.monotonic_ns()}.h5"
    start = time.process_time()
    outcome = run_case(case, path, max_steps=steps)
    seconds = time.process_time() - start
    path.unlink()
    return seconds, outcome.t


def solver_alone(case, steps: int = STEPS) -> tuple[float, float]:
    """(seconds, t reached) of the same ``steps`` steps without recording anything."""
    with one_thread():
        start = time.process_time()
        solver = Solver(case)
        clock = schedule.clock(case)
        state = solver.initial_state()
        for _ in range(steps):
            state, _ = clock.take_step(solver, state, solver.rates(state))
        return time.process_time() - start, solver.time(state)


#: the parts of the run loop timed in place (:func:`where_it_goes`): (owner, attribute, label)
PARTS = (("Solver", "rates", "steps"), ("AdaptiveClock", "take_step", "steps"),
         ("diagnostics", "sample", "samples (the kernel and the row)"),
         ("Decisions", "decided", "decisions (the history and the classification every 100 samples)"),
         ("_Record", "write_rows", "samples and snapshots written (HDF5, checksums)"),
         ("CaseStore", "write_checkpoint", "checkpoints (HDF5, three flushes each)"),
         ("diagnostics", "snapshot", "snapshots (the fields copied)"),
         ("diagnostics", "health", "the health check of every step"),
         ("AdaptiveClock", "events", "the clock's cadence tests of every step"))


def where_it_goes(case, folder: Path, steps: int) -> tuple[float, dict]:
    """(seconds of the steps, {part: seconds}) of one run_case of ``steps`` steps, each part timed in
    place (wall clock, one process: a load change hits the steps and the parts alike); "the rest" is
    the loop itself, the cadences' bookkeeping, the file's creation and the timers' own calls."""
    from hpcves.run import diagnostics, runner
    from hpcves.run.store import CaseStore
    owners = {"Solver": Solver, "AdaptiveClock": schedule.AdaptiveClock, "diagnostics": diagnostics,
              "Decisions": runner.Decisions, "_Record": runner._Record, "CaseStore": CaseStore}
    spent: dict[str, float] = {label: 0.0 for _, _, label in PARTS}
    originals = []
    for owner, name, label in PARTS:
        target = owners[owner]
        original = getattr(target, name, None)
        if original is None:                 # an older tree (--compare) without this part
            continue
        originals.append((target, name, original))

        def timed(*args, _original=original, _label=label, **kwargs):
            start = time.perf_counter()
            try:
                return _original(*args, **kwargs)
            finally:
                spent[_label] += time.perf_counter() - start
        setattr(target, name, timed)
    try:
        start = time.perf_counter()
        run_case(case, folder / f"parts{time.monotonic_ns()}.h5", max_steps=steps)
        total = time.perf_counter() - start
    finally:
        for target, name, original in originals:
            setattr(target, name, original)
    step = spent.pop("steps")
    spent["the rest"] = total - step - sum(spent.values())
    return step, spent


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default="BENCHMARKS.md")
    args = parser.parse_args(argv)
    start = time.time()
    case = the_case()
    runs, alone, placed = [], [], []
    print(f"run loop: {REPEATS} x 2 runs of {STEPS} steps, then {REPEATS_IN_PLACE} x 2 timed in place ...",
          file=sys.stderr)
    with tempfile.TemporaryDirectory() as folder:
        for _ in range(REPEATS):                      # in turn, so that a load change hits both
            runs.append(with_recording(case, Path(folder)))
            alone.append(solver_alone(case))
        for _ in range(REPEATS_IN_PLACE):
            placed.append((where_it_goes(case, Path(folder), STEPS), where_it_goes(case, Path(folder), 2 * STEPS)))
    t_run, t_alone = runs[0][1], alone[0][1]
    recorded, bare = statistics.median(s for s, _ in runs), statistics.median(s for s, _ in alone)
    # each repeat's own ratio, then their median: a load change between repeats cancels in a ratio
    first = statistics.median(r[0] / a[0] - 1 for r, a in zip(runs, alone))

    def share(step, parts):
        return sum(parts.values()) / step

    in_place_first = statistics.median(share(*short) for short, _ in placed)
    in_place_next = statistics.median((sum(long[1].values()) - sum(short[1].values())) / (long[0] - short[0])
                                      for short, long in placed)
    step_seconds, parts = sorted((long for _, long in placed), key=lambda p: share(*p))[len(placed) // 2]
    run = case.run
    samples, snapshots = t_run / run.sample_interval, t_run / run.snapshot_interval
    lines = [f"## {HEADING}", "",
             f"Run {datetime.datetime.now():%Y-%m-%d %H:%M} by `bench/bench_run_loop.py` ({time.time() - start:.0f} s) "
             f"on: {machine()}.", "",
             f"A case of jobs/reproduce/psi048_delta_S.toml (Delta = {EXCESS_LENGTH}, S = {SHEAR_RATE}, "
             f"N = {case.numerics.N} held (the study's N adapts; this case runs on 96 from t = 32.5), "
             f"rtol = {case.numerics.rtol:g}, a sample every {run.sample_interval:g}, "
             f"a snapshot every {run.snapshot_interval:g}), its first {STEPS} steps (to t = {t_run:.4g}: "
             f"~{samples:.0f} samples, ~{snapshots:.0f} snapshots), on one core; medians of {REPEATS} "
             "(the share: the median of each repeat's own).", "",
             "| run | CPU s | per step (ms) |", "| --- | ---: | ---: |",
             f"| run_case: samples, health checks, snapshots, checkpoints, decisions into HDF5 | {recorded:.2f} | "
             f"{1e3 * recorded / STEPS:.3f} |",
             f"| the solver alone, the same steps (to t = {t_alone:.4g}) | {bare:.2f} | {1e3 * bare / STEPS:.3f} |", "",
             f"Recording costs **{first:.0%}** on top of the first {STEPS} steps (the file's creation and its "
             "first checkpoints included).", "",
             f"Timed in place ({REPEATS_IN_PLACE} runs of {STEPS} and of {2 * STEPS} steps, each part of the loop "
             "timed where it runs, against the steps in the same run: wall clock, one process, so a load change "
             f"hits both; medians): **{in_place_first:.0%}** on top of the first {STEPS} steps and "
             f"**{in_place_next:.0%}** on top of the next {STEPS} (what a long run pays; the decisions' share grows "
             f"with the record). Where it goes over {2 * STEPS} steps (the run of median share, "
             f"{share(step_seconds, parts):.0%} "
             f"in all; the steps {step_seconds:.2f} s):", "",
             "| part | share of the steps' time |", "| --- | ---: |"]
    lines += [f"| {label} | {seconds / step_seconds:.1%} |"
              for label, seconds in sorted(parts.items(), key=lambda item: -item[1])]
    replace_section(args.out, HEADING, "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
