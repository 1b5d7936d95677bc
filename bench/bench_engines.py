"""The compiled engine against the numpy one on the period table -> BENCHMARKS.md ("Throughput").

Issue #41 asks that the periods of the adaptive table (bench/bench_adaptive.py: psi_bar in
{0.3, 0.5, 0.7} x S in {80, 160, 320}, Delta = 0.194, N = 128, 640 shear times) agree between the
compiled step and the numpy path to 1e-10 relative. Each case runs with both engines at the table's
settings (fixed dt = 5e-4, rtol = 1e-2 and 3e-2), two runs at a time; the table gives the largest
relative difference of the periods and whether the step sequences were the same, and the seconds of
each engine. As the yardstick of round-off, each case also runs on the numpy engine with S one ulp
higher (a change of the input at the level of one rounding): the spinodal start-up amplifies any
such difference (the two engines' steps differ by 1e-7 relative by step 200 and take different
rejections by step 300 at psi_bar = 0.5, S = 320, rtol = 1e-2), so an adaptive run's periods agree
between two arithmetics only as far as they agree under a one-ulp change of S.

    python bench/bench_engines.py [--settings "rtol = 0.01"]
"""
from __future__ import annotations

import argparse
import math
import multiprocessing
import time

from bench_adaptive import CASES, FIXED_DT
from hpcves.analysis.periodicity import crossing_period
from hpcves.model.params import Case, Numerics, Physics, RunControl
from hpcves.run import diagnostics
from hpcves.run.runner import one_thread

SETTINGS = {f"dt = {FIXED_DT:g}": {"dt": FIXED_DT}, "rtol = 0.01": {"rtol": 1e-2}, "rtol = 0.03": {"rtol": 3e-2}}


#: the numpy engine again, with S one ulp higher: how far round-off alone moves a period
NUDGED = "numpy, S + 1 ulp"


def run(job) -> dict:
    psi_bar, S, setting, engine = job
    with one_thread():
        t_end = max(640.0 / S, 2.0)
        shear_rate = math.nextafter(S, math.inf) if engine == NUDGED else S
        engine = "numpy" if engine == NUDGED else engine
        case = Case(Physics(shear_rate=shear_rate, psi_bar=psi_bar, excess_length=0.194),
                    Numerics(N=128, **SETTINGS[setting]),
                    RunControl(t_end=t_end, sample_interval=1.0 / (5.0 * S), snapshot_interval=t_end,
                               checkpoint_interval=t_end))
        start = time.process_time()
        record = diagnostics.inclination_record(case, engine=engine)
        seconds = time.process_time() - start
    period = crossing_period(record.t, record.theta, t_start=0.25 * t_end).period
    return {"job": job, "period": period, "steps": record.steps, "rejected": record.rejected, "seconds": seconds}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    args = parser.parse_args(argv)
    jobs = [(p, S, setting, engine) for p, S in CASES for setting in args.settings
            for engine in ("compiled", "numpy", NUDGED)]
    with multiprocessing.get_context("spawn").Pool(args.jobs) as pool:
        found = {r["job"]: r for r in pool.imap_unordered(run, jobs)}
    def worst(rows):
        return max(abs(a["period"] - b["period"]) / abs(b["period"]) for a, b in rows)

    def same(rows):
        return sum(a["steps"] == b["steps"] and a["rejected"] == b["rejected"] for a, b in rows)

    print("| setting | compiled against numpy: largest relative period difference | same steps (and rejections) | "
          "numpy against itself, S one ulp higher | same steps | compiled s | numpy s |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for setting in args.settings:
        rows = [(found[(p, S, setting, "compiled")], found[(p, S, setting, "numpy")]) for p, S in CASES]
        nudged = [(found[(p, S, setting, NUDGED)], found[(p, S, setting, "numpy")]) for p, S in CASES]
        print(f"| {setting} | {worst(rows):.1e} | {same(rows)} of {len(rows)} | {worst(nudged):.1e} | "
              f"{same(nudged)} of {len(rows)} | {sum(a['seconds'] for a, _ in rows):.1f} | "
              f"{sum(b['seconds'] for _, b in rows):.1f} |")
    print()
    for (p, S, setting, engine), a in sorted(found.items()):
        b = found[(p, S, setting, "numpy")]
        if engine != "numpy" and (a["steps"], a["rejected"]) != (b["steps"], b["rejected"]):
            print(f"* {setting}, psi_bar = {p}, S = {S:g}: steps (rejected) {a['steps']} ({a['rejected']}) {engine}, "
                  f"{b['steps']} ({b['rejected']}) numpy; periods differ by "
                  f"{abs(a['period'] - b['period']) / b['period']:.1e}")
    return found


if __name__ == "__main__":
    main()
