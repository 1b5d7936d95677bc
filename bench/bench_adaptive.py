"""Adaptive against fixed time steps on the period table -> BENCHMARKS.md (``make bench``).

For psi_bar in {0.3, 0.5, 0.7} x S in {80, 160, 320} at Delta = 0.194, N = 128,
640 shear times (t_end = 8, 4, 2), theta sampled every 1/(5 S): the period of
theta from its mid-line crossings after t_end / 4, for

* a fixed step dt = 3.125e-5 (the reference),
* a fixed step dt = 5e-4 (what jobs/reproduce/periods.toml used before rtol),
* the adaptive step at each tolerance asked for (``--rtol``, default 1e-2 and 3e-2),

with the steps and seconds each took. The reference runs go two at a time
(``--jobs``); the timed runs one at a time, after them.
"""
from __future__ import annotations

import argparse
import multiprocessing
import sys
import time

from hpcves.analysis.periodicity import crossing_period
from hpcves.model.params import Case, Numerics, Physics, RunControl
from hpcves.run import diagnostics
from hpcves.run.runner import one_thread
from report import replace_section

one_thread()          # BLAS and OpenMP at one thread in this process and its workers (threadpoolctl)

CASES = [(psi_bar, S) for psi_bar in (0.3, 0.5, 0.7) for S in (80.0, 160.0, 320.0)]
REFERENCE_DT = 3.125e-5
FIXED_DT = 5e-4


def run(psi_bar: float, S: float, numerics: dict) -> dict:
    """Run one case in memory; theta at its sample times, the period, steps and seconds."""
    t_end = max(640.0 / S, 2.0)
    case = Case(Physics(shear_rate=S, psi_bar=psi_bar, excess_length=0.194), Numerics(N=128, **numerics),
                RunControl(t_end=t_end, sample_interval=1.0 / (5.0 * S), snapshot_interval=t_end,
                           checkpoint_interval=t_end))
    start = time.perf_counter()
    record = diagnostics.inclination_record(case)
    seconds = time.perf_counter() - start
    period = crossing_period(record.t, record.theta, t_start=0.25 * t_end)
    return {"period": period.period, "cycles": period.cycles, "steps": record.steps, "rejected": record.rejected,
            "seconds": seconds}


def _reference(args):
    return run(*args, {"dt": REFERENCE_DT})


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default="BENCHMARKS.md")
    parser.add_argument("--rtol", type=float, nargs="+", default=[1e-2, 3e-2])
    parser.add_argument("--jobs", type=int, default=2, help="reference runs at a time")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    print(f"reference runs at dt = {REFERENCE_DT:g} ({len(CASES)}, {args.jobs} at a time; ~10 min) ...",
          file=sys.stderr)
    with multiprocessing.Pool(args.jobs) as pool:
        references = pool.map(_reference, CASES)
    rows = []
    for (psi_bar, S), ref in zip(CASES, references):
        print(f"psi_bar = {psi_bar}, S = {S:g}: fixed and adaptive ...", file=sys.stderr)
        fixed = run(psi_bar, S, {"dt": FIXED_DT})
        adaptive = {rtol: run(psi_bar, S, {"rtol": rtol}) for rtol in args.rtol}
        rows.append((psi_bar, S, ref, fixed, adaptive))

    def error(r, ref):
        return abs(r["period"] - ref["period"]) / ref["period"]

    header = "| psi_bar | S | period (dt = 3.125e-5) | dt = 5e-4: error | steps | s |"
    rule = "| ---: | ---: | ---: | ---: | ---: | ---: |"
    for rtol in args.rtol:
        header += f" rtol = {rtol:g}: error | steps (rejected) | s |"
        rule += " ---: | ---: | ---: |"
    lines = ["## Adaptive time step: the period table", "",
             f"Run {time.strftime('%Y-%m-%d %H:%M')} by `make bench` ({time.perf_counter() - started:.0f} s), "
             "same machine as above (`bench/bench_adaptive.py`).", "",
             "Delta = 0.194, N = 128, 640 shear times (t_end = 8, 4, 2 for S = 80, 160, 320), theta sampled "
             "every 1/(5 S) (an adaptive step never crosses a sample time); period of theta from its "
             "mid-line crossings after t_end / 4, relative error against the fixed step dt = 3.125e-5. "
             "Seconds: wall time of each run, one at a time on one core (a shared machine: compare within "
             "the table).", "", header, rule]
    totals = {"fixed": [0, 0.0]} | {rtol: [0, 0.0] for rtol in args.rtol}
    worst = {rtol: 0.0 for rtol in args.rtol}
    for psi_bar, S, ref, fixed, adaptive in rows:
        line = (f"| {psi_bar:g} | {S:g} | {ref['period']:.7f} | {error(fixed, ref):.3%} | {fixed['steps']} | "
                f"{fixed['seconds']:.1f} |")
        totals["fixed"][0] += fixed["steps"]
        totals["fixed"][1] += fixed["seconds"]
        for rtol, r in adaptive.items():
            line += f" {error(r, ref):.3%} | {r['steps']} ({r['rejected']}) | {r['seconds']:.1f} |"
            totals[rtol][0] += r["steps"]
            totals[rtol][1] += r["seconds"]
            worst[rtol] = max(worst[rtol], error(r, ref))
        lines.append(line)
    lines.append("")
    fixed_steps, fixed_seconds = totals["fixed"]
    for rtol in args.rtol:
        steps, seconds = totals[rtol]
        met = worst[rtol] <= 1e-3 and steps <= fixed_steps
        lines.append(f"* rtol = {rtol:g}: largest period error **{worst[rtol]:.3%}**, {steps} steps in all "
                     f"against {fixed_steps} at dt = 5e-4 ({steps / fixed_steps:.2f}x), {seconds:.0f} s against "
                     f"{fixed_seconds:.0f} s (target: every period within 0.1 % and no more steps: "
                     f"{'met' if met else 'not met'}).")
    lines.append("")
    section = "\n".join(lines)
    replace_section(args.out, "Adaptive time step: the period table", section)
    print(section)


if __name__ == "__main__":
    main()
