"""Measure the discretisation error of the settled [eta] and N1 against rtol and the spectral tail.

``hpcves analyze`` gives the settled mean of the intrinsic viscosity [eta] and of the first
normal-stress coefficient N1 (model/rheology.py) the error bars theta's mean has: statistical, plus

    |mean - exact| <= STRESS_PER_RTOL[quantity] * rtol + STRESS_PER_TAIL[quantity] * tail

(hpcves/analysis/accuracy.py). This script measures the ratios on the cases the rules of theta were
measured on (analysis/error_rule.py, analysis/spatial_error.py), tank-treading and phase-treading
(tumbling has no rule, as for theta): each at rtol in {0.1, 0.03, 0.01, 0.003} against rtol = 1e-4
at the job files' sampling, and at fixed N in {48, 64, 96, 128} against N = 192 (rtol = 1e-4). The
means are read as ``hpcves analyze`` reads them (hpcves.analysis.stress.settled_mean over theta's
settled part and period).

    .venv/bin/python analysis/stress_error.py --jobs 2 --out docs/stress_error.md   (~30 min on 2 cores)
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import error_rule
import spatial_error
from hpcves.analysis import accuracy
from hpcves.analysis.periodicity import analyze
from hpcves.analysis.stress import settled_mean
from hpcves.model import geometry
from hpcves.model.params import Case, Numerics, Physics, RunControl
from hpcves.numerics.spectral import spectral_tail
from hpcves.run import diagnostics, schedule
from hpcves.run.runner import one_thread
from hpcves.solver.timestepping import Solver

one_thread()

#: (label, regime, psi_bar, Delta, S, N, t_end, sample interval): the time-step cases, the spatial ones
STEP_CASES = [c for c in error_rule.CASES if c[1] != "TU"]
GRID_CASES = [(label, regime, psi_bar, delta, S, None, t_end, interval)
              for label, regime, psi_bar, delta, S, t_end, interval in spatial_error.CASES if regime != "TU"]
RTOLS, REFERENCE_RTOL = error_rule.RTOLS, error_rule.REFERENCE_RTOL
NS, REFERENCE_N = (48, 64, 96, 128), spatial_error.REFERENCE_N
QUANTITIES = ("intrinsic_viscosity", "normal_stress_coefficient")


def run(kind: str, label: str, N: int, rtol: float) -> dict:
    """One case in memory: theta, [eta], N1 and the spectral tails at its sample times; the settled
    means as hpcves analyze reads them."""
    cases = STEP_CASES if kind == "step" else GRID_CASES
    _, regime, psi_bar, delta, S, case_N, t_end, interval = next(c for c in cases if c[0] == label)
    case = Case(Physics(shear_rate=S, psi_bar=psi_bar, excess_length=delta), Numerics(N=N, rtol=rtol),
                RunControl(t_end=t_end, sample_interval=interval, snapshot_interval=t_end, checkpoint_interval=t_end))
    start = time.perf_counter()
    out = {"kind": kind, "label": label, "N": N, "rtol": rtol}
    solver, clock = Solver(case), schedule.clock(case)
    state = solver.initial_state()
    rows = []
    try:
        while True:
            rates = solver.rates(state)
            if clock.sample_due(state):
                m = geometry.moments(rates.shape.z, rates.shape.normal, solver.sp.length)
                tail = max(spectral_tail(solver.sp.fft.rfft(state.theta), N),
                           spectral_tail(rates.psi_hat, N) if rates.psi_hat is not None else 0.0)
                stress = diagnostics.stress(solver, state, rates, m.area)
                rows.append((state.t, m.inclination, tail, *(stress[q] for q in QUANTITIES)))
            if clock.done(state):
                break
            state, _ = clock.take_step(solver, state, rates)
    except Exception as exc:                       # an unresolved run may give out: recorded as such
        return {**out, "failed": f"{type(exc).__name__}: {exc}"[:200], "seconds": time.perf_counter() - start}
    t, theta, tails, *series = np.array(rows).T
    a = analyze(t, theta)
    settled = t >= a.t_settle
    out |= {"tail": float(tails[settled].max()) if settled.any() else float(tails.max()),
            "period": a.period.period, "seconds": time.perf_counter() - start}
    for name, x in zip(QUANTITIES, series):
        found = settled_mean(t, x, a.t_settle, a.period.period, a.period.error)
        out |= {name: found.mean, f"{name}_err": found.error, f"{name}_amplitude": found.amplitude}
    return out


def key(r: dict) -> str:
    return f"{r['kind']}|{r['label']}|{r['N']}|{r['rtol']:g}"


def _stat(r: dict, ref: dict, name: str) -> float:
    return float(np.nan_to_num(r[f"{name}_err"]) + np.nan_to_num(ref[f"{name}_err"]))


def render(results: dict) -> tuple[list[str], dict, bool]:
    """The Markdown report, the largest ratios {(quantity, "rtol" | "tail"): ratio}, and whether the rule of
    accuracy.py covers every run."""
    seconds = sum(r["seconds"] for r in results.values())
    worst = {(q, part): 0.0 for q in QUANTITIES for part in ("rtol", "tail")}
    covered = True
    head = ("| case | S | psi_bar | Delta | {x} | mean [eta] | \\|d[eta]\\| | stat | excess / {y} | mean N1 | "
            "\\|dN1\\| | stat | excess / {y} |")
    rule = "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"
    lines = ["# The discretisation error of the settled [eta] and N1", "",
             f"Measured {time.strftime('%Y-%m-%d')} by `analysis/stress_error.py` ({seconds / 60:.0f} min of runs on "
             "a shared 2-core machine); hpcves/analysis/accuracy.py states the rule these numbers set. Means over "
             "theta's settled part and whole periods (hpcves.analysis.stress.settled_mean), as `hpcves analyze` "
             "reads them. |d|: the difference from the reference run; stat: what the two means' statistical errors "
             "allow together; excess: the part of |d| beyond that, per unit rtol or tail.", ""]
    for kind, cases, variants, x, y in (("step", STEP_CASES, RTOLS, "rtol", "rtol"),
                                        ("grid", GRID_CASES, NS, "N", "tail")):
        title = ("## Against rtol (reference rtol = 1e-4, each case at its N)" if kind == "step" else
                 f"## Against the spectral tail (reference N = {REFERENCE_N}, rtol = {spatial_error.RTOL:g})")
        lines += [title, "", head.format(x=x, y=y), rule]
        for label, regime, psi_bar, delta, S, N, *_ in cases:
            ref_key = f"{kind}|{label}|{N if kind == 'step' else REFERENCE_N}|" \
                      f"{REFERENCE_RTOL if kind == 'step' else spatial_error.RTOL:g}"
            ref = results.get(ref_key)
            if ref is None or "failed" in ref:
                lines.append(f"| {label} ({regime}) | {S:g} | {psi_bar:g} | {delta:.3g} | reference "
                             f"{ref['failed'] if ref else 'not run'} | | | | | | | | |")
                continue
            lines.append(f"| {label} ({regime}) | {S:g} | {psi_bar:g} | {delta:.3g} | "
                         f"{REFERENCE_RTOL if kind == 'step' else REFERENCE_N:g} | "
                         f"{ref[QUANTITIES[0]]:.6f} | | {ref[QUANTITIES[0] + '_err']:.1e} | | "
                         f"{ref[QUANTITIES[1]]:.6f} | | {ref[QUANTITIES[1] + '_err']:.1e} | |")
            for v in variants:
                k = f"{kind}|{label}|{N if kind == 'step' else v}|{v if kind == 'step' else spatial_error.RTOL:g}"
                r = results.get(k)
                if r is None or "failed" in r:
                    lines.append(f"| | | | | {v:g} | {r['failed'] if r else 'not run'} | | | | | | | |")
                    continue
                scale = v if kind == "step" else r["tail"]
                ruled = kind == "step" or r["tail"] <= accuracy.TAIL_RULED_UP_TO
                cells = []
                for name in QUANTITIES:
                    d = abs(r[name] - ref[name])
                    stat = _stat(r, ref, name)
                    excess = max(d - stat, 0.0) / scale if scale > 0 else 0.0
                    if ruled:
                        worst[(name, "rtol" if kind == "step" else "tail")] = max(
                            worst[(name, "rtol" if kind == "step" else "tail")], excess)
                        bar = accuracy.stress_step_error(name, v) if kind == "step" else \
                            accuracy.stress_grid_error(name, r["tail"])
                        covered &= bool(d <= stat + bar)
                    cells += [f"{r[name]:.6f}", f"{d:.1e}", f"{stat:.1e}", f"{excess:.3g}"]
                shown = f"{v:g}" + ("" if kind == "step" else f" (tail {r['tail']:.1e}{'' if ruled else ' *'})")
                lines.append(f"| | | | | {shown} | " + " | ".join(cells) + " |")
        lines.append("")
    lines += [f"\\* a tail beyond {accuracy.TAIL_RULED_UP_TO:g}: no bar (accuracy.TAIL_RULED_UP_TO), not in the "
              "largest ratios.", "",
              "Largest ratios (excess per unit rtol / tail): "
              + ", ".join(f"{q} {part} {worst[(q, part)]:.3g}" for q, part in worst) + ". The rule in "
              f"hpcves/analysis/accuracy.py (STRESS_PER_RTOL = {accuracy.STRESS_PER_RTOL}, STRESS_PER_TAIL = "
              f"{accuracy.STRESS_PER_TAIL}) "
              + ("covers every run above." if covered else "DOES NOT COVER every run above."), ""]
    return lines, worst, covered


def _task(task):
    return run(*task)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/stress_error.md")
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--cache", default="out/stress_error.json", help="results so far (a stopped call resumes)")
    args = parser.parse_args(argv)
    cache = Path(args.cache)
    results = json.loads(cache.read_text()) if cache.exists() else {}
    tasks = [("step", c[0], c[5], r) for c in STEP_CASES for r in (REFERENCE_RTOL,) + RTOLS] \
        + [("grid", c[0], N, spatial_error.RTOL) for c in GRID_CASES for N in (REFERENCE_N,) + NS]
    tasks = [t for t in tasks if f"{t[0]}|{t[1]}|{t[2]}|{t[3]:g}" not in results]
    spatial_error.run_cached(_task, tasks, key, results, cache, args.jobs)
    lines, _, covered = render(results)
    Path(args.out).write_text("\n".join(lines))
    print("\n".join(lines))
    return 0 if covered else 1


if __name__ == "__main__":
    sys.exit(main())
