"""The saturating bending law against the linear one -> docs/bending_law.md.

1. The period table (psi_bar in {0.3, 0.5, 0.7} x S in {80, 160, 320}, Delta =
   0.194, N = 128, rtol = 1e-2, 640 shear times, theta every 1/(5 S)) under both
   laws: the periods must agree to 1e-4 (issue 16). Also the range of psi, which
   says how far outside [0, 1] the law was asked about.
2. Deflated cases where the linear law gives out (Delta = 2.3, psi_bar = 0.5,
   S = 20 and psi_bar = 0.48, S = 28; Delta = 1.3, psi_bar = 0.48, S = 5): how far
   each law gets in t_end = 3, and the range of psi on the way.

    .venv/bin/python analysis/bending_law.py --jobs 2      (~10 min on 2 cores)
"""
from __future__ import annotations

import argparse
import multiprocessing
import sys
import time

import hpcves  # noqa: F401  (pins BLAS to one thread before numpy loads)
import numpy as np

from hpcves import diagnostics
from hpcves.params import Case, Numerics, Physics, RunControl
from hpcves.periodicity import crossing_period
from hpcves.stepcontrol import StepSizeError

LAWS = ("linear", "saturating")
TABLE = [(psi_bar, S) for psi_bar in (0.3, 0.5, 0.7) for S in (80.0, 160.0, 320.0)]
#: (psi_bar, Delta, S, N)
DEFLATED = [(0.5, 2.3, 20.0, 128), (0.48, 2.3, 28.0, 128), (0.48, 1.3, 5.0, 128)]
RTOL = 1e-2


def period_run(psi_bar: float, S: float, law: str) -> dict:
    t_end = max(640.0 / S, 2.0)
    case = Case(Physics(shear_rate=S, psi_bar=psi_bar, excess_length=0.194, bending_law=law),
                Numerics(N=128, rtol=RTOL),
                RunControl(t_end=t_end, sample_interval=1.0 / (5.0 * S), snapshot_interval=t_end,
                           checkpoint_interval=t_end))
    record = diagnostics.inclination_record(case)
    period = crossing_period(record.t, record.theta, t_start=0.25 * t_end)
    return {"kind": "period", "psi_bar": psi_bar, "S": S, "law": law, "period": period.period,
            "cycles": period.cycles, "psi_range": record.psi_range, "steps": record.steps}


def deflated_run(psi_bar: float, delta: float, S: float, N: int, law: str, t_end: float = 3.0) -> dict:
    """As far as the case gets in t_end: stepped in pieces of 0.1 so that a failure has a time."""
    start = time.perf_counter()
    low, high, reached, state, outcome = np.inf, -np.inf, 0.0, None, "ran to t_end"
    t = 0.0
    while t < t_end - 1e-12:
        t = min(t + 0.1, t_end)
        case = Case(Physics(shear_rate=S, psi_bar=psi_bar, excess_length=delta, bending_law=law),
                    Numerics(N=N, rtol=RTOL),
                    RunControl(t_end=t, sample_interval=0.01, snapshot_interval=t, checkpoint_interval=t))
        try:
            with np.errstate(all="raise"):
                record = diagnostics.inclination_record(case, state)
        except (StepSizeError, ArithmeticError, FloatingPointError) as exc:
            outcome = f"{type(exc).__name__} after t = {reached:.2f}"
            break
        state, reached = record.state, t
        low, high = min(low, record.psi_range[0]), max(high, record.psi_range[1])
        if not (-0.25 <= low and high <= 1.1):
            outcome = f"psi left [-0.25, 1.1] (run.psi_min, psi_max) by t = {reached:.2f}"
            break
    return {"kind": "deflated", "psi_bar": psi_bar, "delta": delta, "S": S, "N": N, "law": law,
            "reached": reached, "outcome": outcome, "psi_range": (low, high),
            "seconds": time.perf_counter() - start}


def _task(task):
    return period_run(*task[1:]) if task[0] == "period" else deflated_run(*task[1:])


def render(results: list[dict], seconds: float) -> tuple[list[str], bool]:
    periods = {(r["psi_bar"], r["S"], r["law"]): r for r in results if r["kind"] == "period"}
    lines = ["# The saturating bending law against the linear one", "",
             f"Measured {time.strftime('%Y-%m-%d')} by `analysis/bending_law.py` ({seconds / 60:.0f} min of runs on "
             f"a shared 2-core machine). rtol = {RTOL:g}; hpcves/bending.py has the law, docs/numerics.md "
             "(\"Bending law\") the reasoning.", "",
             "## The period table at Delta = 0.194 (N = 128, 640 shear times, period after t_end / 4)", "",
             "| psi_bar | S | psi range (saturating) | period, linear | period, saturating | relative difference |",
             "| ---: | ---: | --- | ---: | ---: | ---: |"]
    worst = 0.0
    for psi_bar, S in TABLE:
        lin, sat = periods[(psi_bar, S, "linear")], periods[(psi_bar, S, "saturating")]
        d = abs(sat["period"] - lin["period"]) / lin["period"]
        worst = max(worst, d)
        lo, hi = sat["psi_range"]
        lines.append(f"| {psi_bar:g} | {S:g} | [{lo:.4f}, {hi:.4f}] | {lin['period']:.8g} | {sat['period']:.8g} "
                     f"| {d:.1e} |")
    ok = worst <= 1e-4
    lines += ["", f"Largest relative difference {worst:.1e} "
              + ("(within the 1e-4 asked for)." if ok else "-- MORE than the 1e-4 asked for."), "",
              "## Deflated cases (t_end = 3)", "",
              "| psi_bar | Delta | S | N | law | outcome | psi range | seconds |",
              "| ---: | ---: | ---: | ---: | --- | --- | --- | ---: |"]
    for psi_bar, delta, S, N in DEFLATED:
        for law in LAWS:
            r = next(x for x in results if x["kind"] == "deflated" and x["law"] == law
                     and (x["psi_bar"], x["delta"], x["S"]) == (psi_bar, delta, S))
            lo, hi = r["psi_range"]
            lines.append(f"| {psi_bar:g} | {delta:g} | {S:g} | {N} | {law} | {r['outcome']} | "
                         f"[{lo:.4f}, {hi:.4f}] | {r['seconds']:.0f} |")
    return lines, ok


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/bending_law.md")
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args(argv)
    tasks = [("deflated", *c, law) for c in DEFLATED for law in LAWS] + \
            [("period", psi_bar, S, law) for psi_bar, S in TABLE for law in LAWS]
    started = time.perf_counter()
    results = []
    with multiprocessing.Pool(args.jobs) as pool:
        for i, r in enumerate(pool.imap_unordered(_task, tasks)):
            results.append(r)
            print(f"  {i + 1}/{len(tasks)}: {r['kind']} psi_bar = {r['psi_bar']:g}, S = {r['S']:g}, {r['law']}",
                  file=sys.stderr)
    lines, ok = render(results, time.perf_counter() - started)
    text = "\n".join(lines) + "\n"
    with open(args.out, "w") as f:
        f.write(text)
    print(text)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
