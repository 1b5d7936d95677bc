"""The saturating bending law against the linear one -> docs/bending_law.md.

1. The period table (psi_bar in {0.3, 0.5, 0.7} x S in {80, 160, 320}, Delta =
   0.194, N = 128, rtol = 1e-2, 640 shear times, theta every 1/(5 S)) under both
   laws: the periods must agree to 1e-4 (issue 16). Also the range of psi, which
   says how far outside [0, 1] the law was asked about.
2. Deflated cases where the linear law gives out (the three of jobs/reproduce/ it
   stopped as under-resolved) and the two of issue 16's prototype (Delta = 2.3,
   psi_bar = 0.5, S = 20 and psi_bar = 0.48, S = 28), run as ``hpcves run`` runs
   them (health and resolution watched) to t_end = 4: outcome, range of psi and
   largest spectral tail.
3. Moderately deflated cases (Delta = 0.94, TU at S = 5 and S = 20) at tight rtol, where
   psi overshoots 1 by a few per cent: the size of the law's effect there.

    .venv/bin/python analysis/bending_law.py --jobs 2      (~10 min on 2 cores)
"""
from __future__ import annotations

import argparse
import multiprocessing
import sys
import time

from hpcves.analysis.periodicity import crossing_period, estimate_period
from hpcves.analysis.regimes import flip_period
from hpcves.model.params import Case, Numerics, Physics, RunControl
from hpcves.run import diagnostics
from hpcves.run.runner import one_thread

one_thread()          # BLAS and OpenMP at one thread in this process and its workers (threadpoolctl)

LAWS = ("linear", "saturating")
TABLE = [(psi_bar, S) for psi_bar in (0.3, 0.5, 0.7) for S in (80.0, 160.0, 320.0)]
#: (psi_bar, Delta, S, N): the cases of jobs/reproduce/ that the linear law stopped (under-resolved
#: tips), and the two that issue 16's prototype ran
DEFLATED = [(0.3, 2.3, 5.0, 128), (0.3, 2.3, 20.0, 128), (0.48, 1.3, 5.0, 128), (0.5, 2.3, 20.0, 128),
            (0.48, 2.3, 28.0, 128)]
RTOL = 1e-2
#: (psi_bar, Delta, S, N, t_end, rtol): moderately deflated, where psi overshoots 1 by a few per cent at
#: the tips (the TU case of docs/error_rule.md, tight rtol: its period depends on the orbit rtol picks)
MODERATE = [(0.5, 0.94, 5.0, 64, 60.0, 1e-5), (0.5, 0.94, 20.0, 64, 20.0, 1e-4)]


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


def deflated_run(psi_bar: float, delta: float, S: float, N: int, law: str, t_end: float = 4.0) -> dict:
    """The case as ``hpcves run`` runs it (health and resolution watched) to t_end, in a scratch file."""
    import tempfile
    from pathlib import Path

    from hpcves.run import runner
    from hpcves.run.store import STATUS_NAMES, CaseStore, open_file

    case = Case(Physics(shear_rate=S, psi_bar=psi_bar, excess_length=delta, bending_law=law),
                Numerics(N=N, rtol=RTOL),
                RunControl(t_end=t_end, sample_interval=0.01, snapshot_interval=t_end, checkpoint_interval=t_end))
    with tempfile.TemporaryDirectory() as scratch, open_file(Path(scratch) / "case.h5", "w-") as f:
        store = CaseStore.create(f, case)
        outcome = runner.run(store, f.flush)
        n = store.n_samples
        series = {k: store.timeseries()[k][:n] for k in ("psi_min", "psi_max", "tail_theta", "tail_psi")}
    return {"kind": "deflated", "psi_bar": psi_bar, "delta": delta, "S": S, "N": N, "law": law,
            "reached": outcome.t, "steps": outcome.steps,
            "outcome": STATUS_NAMES[outcome.status]
            + (f": {outcome.message.split(' (')[0]}" if outcome.message else ""),
            "psi_range": (float(series["psi_min"].min()), float(series["psi_max"].max())),
            "tail": float(max(series["tail_theta"].max(), series["tail_psi"].max())), "seconds": outcome.wall}


def moderate_run(psi_bar: float, delta: float, S: float, N: int, t_end: float, rtol: float, law: str) -> dict:
    case = Case(Physics(shear_rate=S, psi_bar=psi_bar, excess_length=delta, bending_law=law),
                Numerics(N=N, rtol=rtol),
                RunControl(t_end=t_end, sample_interval=min(0.02, 1.0 / (10.0 * S)), snapshot_interval=t_end,
                           checkpoint_interval=t_end))
    record = diagnostics.inclination_record(case)
    keep = record.t >= 0.25 * t_end
    flips = record.theta[keep].min() < 0
    p = (flip_period if flips else estimate_period)(record.t[keep], record.theta[keep])
    return {"kind": "moderate", "psi_bar": psi_bar, "delta": delta, "S": S, "N": N, "law": law, "rtol": rtol,
            "regime": "TU" if flips else "PT or TT", "period": p.period, "period_err": p.error,
            "psi_range": record.psi_range, "steps": record.steps}


def _task(task):
    kind, args = task[0], task[1:]
    return {"period": period_run, "deflated": deflated_run, "moderate": moderate_run}[kind](*args)


def render(results: list[dict], seconds: float) -> tuple[list[str], bool]:
    periods = {(r["psi_bar"], r["S"], r["law"]): r for r in results if r["kind"] == "period"}
    lines = ["# The saturating bending law against the linear one", "",
             f"Measured {time.strftime('%Y-%m-%d')} by `analysis/bending_law.py` ({seconds / 60:.0f} min of runs on "
             f"a shared 2-core machine). rtol = {RTOL:g}; hpcves/model/bending.py has the law, docs/numerics.md "
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
              "## Deflated cases, run as `hpcves run` runs them (t_end = 4)", "",
              "Largest spectral tail of theta and psi over the run (the watch stops a run above "
              "run.max_spectral_tail = 3e-3).", "",
              "| psi_bar | Delta | S | N | law | outcome | reached t | psi range | largest tail | steps |",
              "| ---: | ---: | ---: | ---: | --- | --- | ---: | --- | ---: | ---: |"]
    for psi_bar, delta, S, N in DEFLATED:
        for law in LAWS:
            r = next(x for x in results if x["kind"] == "deflated" and x["law"] == law
                     and (x["psi_bar"], x["delta"], x["S"]) == (psi_bar, delta, S))
            lo, hi = r["psi_range"]
            lines.append(f"| {psi_bar:g} | {delta:g} | {S:g} | {N} | {law} | {r['outcome']} | {r['reached']:.3g} | "
                         f"[{lo:.4f}, {hi:.4f}] | {r['tail']:.1e} | {r['steps']} |")
    lines += ["", "## Moderately deflated (Delta = 0.94): where the law shows", "",
              "psi overshoots 1 by a few per cent at the tips, where the saturating law's B' has begun to fade "
              "(by 2.5 % at 1 + w/2). Period after t_end / 4 (a tumbling one from sin 2 theta).", "",
              "| psi_bar | Delta | S | N | rtol | law | motion | psi range | period | steps |",
              "| ---: | ---: | ---: | ---: | ---: | --- | --- | --- | ---: | ---: |"]
    for psi_bar, delta, S, N, t_end, rtol in MODERATE:
        both = {}
        for law in LAWS:
            r = next(x for x in results if x["kind"] == "moderate" and x["law"] == law
                     and (x["psi_bar"], x["delta"], x["S"]) == (psi_bar, delta, S))
            both[law] = r
            lo, hi = r["psi_range"]
            lines.append(f"| {psi_bar:g} | {delta:g} | {S:g} | {N} | {rtol:g} | {law} | {r['regime']} | "
                         f"[{lo:.4f}, {hi:.4f}] | {r['period']:.6g} +- {r['period_err']:.1g} | {r['steps']} |")
        d = abs(both["saturating"]["period"] - both["linear"]["period"]) / both["linear"]["period"]
        lines.append(f"| | | | | | | | relative difference | {d:.1e} | |")
    return lines, ok


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/bending_law.md")
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args(argv)
    tasks = [("moderate", *c, law) for c in MODERATE for law in LAWS] + \
            [("deflated", *c, law) for c in DEFLATED for law in LAWS] + \
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
