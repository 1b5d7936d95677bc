"""What a viscosity contrast costs (physics.viscosity_ratio != 1) -> BENCHMARKS.md (``make bench``).

Issue #42 asks that a step with lambda != 1 cost at most 1.5 times the lambda = 1 step at N = 128.
One process, one core: for each case, N and lambda a solver at fixed dt, warmed up, then REPEATS
timings of STEPS steps each (CPU of this thread), every solver in turn within a repeat so that a
change of load hits all of them; the table gives medians and the ratio to lambda = 1 of the same
case and N. The GMRES iterations a solve took are counted on the numpy engine at the last state
(the same iteration as the compiled engine's, flow.MembraneFlow._solve_with_contrast).
"""
from __future__ import annotations

import argparse
import datetime
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import hpcves.model.flow as flow_module  # noqa: E402
from bench_solver import machine  # noqa: E402
from hpcves.model.params import Case, Numerics, Physics, RunControl  # noqa: E402
from hpcves.run.runner import one_thread  # noqa: E402
from hpcves.solver.timestepping import Solver  # noqa: E402
from report import replace_section  # noqa: E402

#: label -> (Physics keywords, dt)
CASES = {"psi_bar = 0.3, Delta = 0.194, S = 80": (dict(psi_bar=0.3, shear_rate=80.0), 1e-3),
         "psi_bar = 0.5, Delta = 0.94, S = 20": (dict(psi_bar=0.5, excess_length=0.94, shear_rate=20.0), 2e-4)}
SIZES = (64, 128, 256)
RATIOS = (1.0, 0.5, 4.0, 10.0)
STEPS = 40
REPEATS = 5
HEADING = "Viscosity contrast: the cost of a step"


def solver(label: str, N: int, viscosity_ratio: float, engine: str | None = None) -> Solver:
    physics, dt = CASES[label]
    return Solver(Case(Physics(viscosity_ratio=viscosity_ratio, **physics), Numerics(N=N, dt=dt),
                       RunControl(t_end=1e3)), engine=engine)


def seconds_per_step(s: Solver, state):
    start = time.thread_time()
    for _ in range(STEPS):
        state, _, _ = s.step(state)
    return (time.thread_time() - start) / STEPS, state


def iterations(label: str, N: int, viscosity_ratio: float, state) -> int:
    """GMRES iterations of the velocity at ``state`` (the numpy engine's solve, counted)."""
    counted = []
    original = flow_module.gmres

    def counting(*args, **kwargs):
        result = original(*args, **kwargs)
        counted.append(result[2])
        return result

    flow_module.gmres = counting
    try:
        solver(label, N, viscosity_ratio, engine="numpy").rates(state)
    finally:
        flow_module.gmres = original
    return counted[0]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default="BENCHMARKS.md")
    parser.add_argument("--N", type=int, nargs="+", default=list(SIZES))
    args = parser.parse_args(argv)
    start = time.time()
    keys = [(label, N, lam) for label in CASES for N in args.N for lam in RATIOS]
    print(f"viscosity contrast: {len(keys)} solvers, {REPEATS} x {STEPS} steps each ...", file=sys.stderr)
    with one_thread():
        solvers = {key: solver(*key) for key in keys}
        states = {}
        for key, s in solvers.items():                      # warm-up: compilation, the first (Euler) steps
            state = s.initial_state()
            for _ in range(10):
                state, _, _ = s.step(state)
            states[key] = state
        samples = {key: [] for key in keys}
        for _ in range(REPEATS):
            for key, s in solvers.items():
                seconds, states[key] = seconds_per_step(s, states[key])
                samples[key].append(seconds)
    times = {key: statistics.median(v) for key, v in samples.items()}
    rows = ["| case | N | lambda = 1 (ms) | " + " | ".join(f"lambda = {lam:g} (ms, ratio, GMRES its)"
                                                        for lam in RATIOS[1:]) + " |",
            "| --- | ---: | ---: | " + " | ".join("---:" for _ in RATIOS[1:]) + " |"]
    for label in CASES:
        for N in args.N:
            one = times[(label, N, 1.0)]
            cells = [f"{1e3 * times[(label, N, lam)]:.3f}, {times[(label, N, lam)] / one:.2f}x, "
                     f"{iterations(label, N, lam, states[(label, N, lam)])}" for lam in RATIOS[1:]]
            rows.append(f"| {label} | {N} | {1e3 * one:.3f} | " + " | ".join(cells) + " |")
    lines = [f"## {HEADING}", "",
             f"Run {datetime.datetime.now():%Y-%m-%d %H:%M} by `bench/bench_contrast.py` ({time.time() - start:.0f} s) "
             f"on: {machine()}.", "",
             f"A step of the compiled engine at fixed dt on one core with `physics.viscosity_ratio` = lambda, "
             f"against lambda = 1; medians of {REPEATS} x {STEPS} steps (CPU), all solvers in turn each repeat; "
             "the GMRES iterations of the velocity at the last state.", "", *rows, "",
             "A step with a contrast adds to the equal-viscosity step the double layer's matrix (O(N^2)) and, "
             "per GMRES iteration, one equal-viscosity solve (the tension's triangular solves and one "
             "single-layer product, O(N^2)) and one double-layer product (flow.MembraneFlow._solve_with_contrast; "
             "docs/numerics.md, \"Viscosity contrast\"). The equal-viscosity step's Cholesky factorisation "
             "is O(N^3), so the ratio falls as N grows and rises with the iterations a shape needs."]
    replace_section(args.out, HEADING, "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
