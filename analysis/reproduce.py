"""The reproduction study -> REPRODUCTION.md and docs/reproduction/ (``make reproduce``).

Runs the campaigns of jobs/reproduce/ (coarse grids, ~1 h on 2 cores) or the
full grids (``--grid full``) with ``mpirun -n NP hpcves campaign --resume``,
so an interrupted reproduction continues where it stopped; analyzes each with
``hpcves analyze``; and writes REPRODUCTION.md: the PT period table at
Delta = 0.194, S_C against psi_bar and against B2, the three phase diagrams,
and a list of everything that looks unconverged.
"""
from __future__ import annotations

import argparse
import datetime
import json
import math
import platform
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

from hpcves import accuracy
from hpcves.analysis import analyze, markdown_table, read_source
from hpcves.campaign_file import read_table
from hpcves.search_campaign import critical_table
from hpcves.study import load_study

COARSE = ("homogeneous", "periods", "psi048_cases", "sc_b2", "sc_psi", "psi048_delta_S", "delta094_S_psi",
          "delta230_S_psi")
FULL = {"periods": "jobs/reproduce/full/periods.toml", "sc_psi": "jobs/reproduce/full/sc_psi.toml",
        "sc_b2": "jobs/reproduce/full/sc_b2.toml", "psi048_delta_S": "jobs/psi048_delta_S.toml",
        "delta094_S_psi": "jobs/delta094_S_psi.toml", "delta230_S_psi": "jobs/delta230_S_psi.toml"}
FIGURES = {"coarse": Path("docs/reproduction"), "full": Path("docs/reproduction/full")}
MIN_GOOD_CYCLES = 5          # PT cases with fewer settled periods are flagged


def run_campaigns(jobs: dict, mpirun: list[str], np_: int, hpcves: str, ledger: Path) -> dict:
    """Run (or continue) every campaign; return its wall time in seconds in this call (0 if it was
    complete). The wall times of every call are added up in ``ledger`` (JSON), so that an interrupted
    and resumed reproduction still reports what all of it took."""
    walls = {}
    for name, toml in jobs.items():
        start = time.monotonic()
        command = mpirun + ["-n", str(np_), hpcves, "campaign", toml, "--resume", "--quiet"]
        print(f"[{name}] {' '.join(command[-6:])}", flush=True)
        try:
            result = subprocess.run(command)
        finally:
            walls[name] = time.monotonic() - start
            _add_walls(ledger, {name: walls[name]})
        if result.returncode not in (0, 1):        # 1: some case failed -- reported in REPRODUCTION.md
            sys.exit(f"campaign {toml} stopped with exit status {result.returncode}; rerun make reproduce "
                     "to continue it")
    return walls


def _add_walls(ledger: Path, walls: dict) -> dict:
    """Add ``walls`` (seconds per campaign) to the totals kept in ``ledger``; the totals."""
    totals = json.loads(ledger.read_text()) if ledger.exists() else {}
    for name, wall in walls.items():
        totals[name] = totals.get(name, 0.0) + wall
    ledger.parent.mkdir(parents=True, exist_ok=True)
    ledger.write_text(json.dumps(totals, indent=1))
    return totals


def analyse(jobs: dict, out: Path) -> dict:
    reports = {}
    for name, toml in jobs.items():
        study = load_study(toml)
        print(f"[{name}] analyze {study.output}", flush=True)
        reports[name] = analyze(study.output, out / name)
    return reports


def copy_figures(reports: dict, directory: Path) -> dict:
    """Copy the PNG figures REPRODUCTION.md shows into ``directory``; {name: [paths]}."""
    directory.mkdir(parents=True, exist_ok=True)
    shown = {}
    for name, report in reports.items():
        paths = []
        for path in report.written:
            if path.suffix == ".png" and path.parent.name != "cases":
                target = directory / f"{name}_{path.name}"
                shutil.copyfile(path, target)
                paths.append(target)
        shown[name] = paths
    return shown


def _fmt(value, spec=".4g") -> str:
    return format(value, spec) if isinstance(value, float) and math.isfinite(value) else ""


def period_table(report) -> str:
    rows = report.rows
    psis = sorted({r["psi_bar"] for r in rows})
    rates = sorted({r["shear_rate"] for r in rows})
    cells = {(r["psi_bar"], r["shear_rate"]): r for r in rows}
    body = []
    for psi in psis:
        line = [f"{psi:g}"]
        for s in rates:
            r = cells[(psi, s)]
            if r["regime"] in ("PT", "TU"):
                error, dominant = accuracy.error_bar(r, "period")
                line.append(f"{r['period']:.4g} +- {error:.1g} [{dominant}] (S T = {s * r['period']:.3g})"
                            + (" TU" if r["regime"] == "TU" else ""))
            else:
                line.append(r["regime"])
        body.append(line)
    return markdown_table(["psi_bar \\ S"] + [f"{s:g}" for s in rates], body)


def doubts(reports: dict) -> list[str]:
    """Everything that looks unconverged or unresolved, one line each."""
    lines = []
    for name, report in reports.items():
        for r in report.rows:
            label = (f"{name} case {r['case']} (S = {r['shear_rate']:g}, psi_bar = {r['psi_bar']:g}, "
                     f"Delta = {r['excess_length']:g}, B2 = {r['B2']:g})")
            if r["status"] != "finished":
                lines.append(f"{label}: {r['status']}: {r['reason']}")
            elif r["regime"] == "undecided":
                lines.append(f"{label}: undecided -- {r['reason']}")
            elif r["regime"] in ("PT", "TU") and r["cycles"] < MIN_GOOD_CYCLES:
                lines.append(f"{label}: {r['regime']} from only {r['cycles']:.1f} settled periods")
            elif r["regime"] in ("PT", "TU") and (bar := accuracy.error_bar(r, "period"))[0] > 0.005 * r["period"]:
                lines.append(f"{label}: period uncertain by {bar[0] / r['period']:.1%} ({bar[1]} dominates)")
        for s in report.searches:
            if s["status"] != "converged":
                lines.append(f"{name}: search psi_bar = {s['psi_bar']:g}, B2 = {s['B2']:g}: {s['status']} -- "
                             f"{s['reason']}")
    return lines


def numerics_line(toml: str) -> str:
    study = load_study(toml)
    base = study.base
    rule = study.times
    end = (f"t_end = {rule.t_end:g}" if rule.t_end is not None else
           f"t_end = max({rule.shear_times:g} / S, {rule.t_end_min:g})" if rule.shear_times is not None
           else f"t_end = {base.run.t_end:g}")
    sampling = (f"samples every min({base.run.sample_interval:g}, 1/({rule.samples_per_shear_time:g} S))"
                if rule.samples_per_shear_time is not None else f"samples every {base.run.sample_interval:g}")
    num = base.numerics
    step = f"adaptive step, rtol = {num.rtol:g}" if num.adaptive else f"dt = {num.dt:g}"
    return f"N = {num.N}, {step}, {end}, {sampling}"


def write_report(path: Path, grid: str, jobs: dict, reports: dict, figures: dict, walls: dict, np_: int) -> None:
    total = sum(walls.values())
    lines = [
        "# Reproduction of the published studies (`make reproduce`)", "",
        f"Written by `analysis/reproduce.py --grid {grid}` on {datetime.date.today()} "
        f"({platform.node()}, {platform.processor() or platform.machine()}, {np_} MPI ranks). "
        f"Wall time of the campaigns in this call: {total / 60:.0f} min "
        + ", ".join(f"{n} {w / 60:.1f}" for n, w in walls.items()) + " (0 where they were complete already).",
        "", "Every campaign and its numerics:", ""]
    compute = {name: sum(row["wall"] for row in read_table(load_study(toml).output).rows)
               for name, toml in jobs.items()}
    lines += [f"* `{toml}` ({name}): {numerics_line(toml)}; {len(reports[name].rows)} cases, "
              f"{compute[name] / 60:.1f} core-minutes" for name, toml in jobs.items()]
    lines += ["", f"In all {sum(compute.values()) / 3600:.2f} core-hours of cases (summed over every call that "
              f"advanced them), that is {sum(compute.values()) / np_ / 3600:.2f} h on {np_} cores."]
    lines += ["", "Regimes are decided by `hpcves analyze` (docs/analysis.md) with its default thresholds; "
              f"the per-case figures and tables are in `out/reproduce/{grid}/<campaign>/`.", ""]

    lines += ["## PT period at Delta = 0.194", "",
              "Period of theta +- its uncertainty (statistical + time-step discretisation; in brackets the part "
              "that dominates); S T is the period in shear times (a 1/S law makes it constant).", "",
              period_table(reports["periods"]), ""]
    lines += ["## Critical shear rate at Delta = 0.194", "",
              "S_C is the geometric middle of the final bracket [largest TT, smallest PT/TU].", "",
              "### Against psi_bar (B2 = 0.1)", "", critical_table(list(reports["sc_psi"].searches), ["psi_bar"]), "",
              "### Against B2 at psi_bar = 0.3", "", critical_table(list(reports["sc_b2"].searches), ["B2"]), ""]
    for name in ("sc_psi", "sc_b2"):
        lines += [f"![{name}]({p.as_posix()})" for p in figures[name]] + [""]
    lines += ["## Phase diagrams", ""]
    for name, title in (("psi048_delta_S", "Delta x S at psi_bar = 0.48"),
                        ("delta094_S_psi", "S x psi_bar at Delta = 0.94"),
                        ("delta230_S_psi", "S x psi_bar at Delta = 2.30")):
        counts = ", ".join(f"{n} {r}" for r, n in reports[name].counts().items())
        lines += [f"### {title}", "", f"{counts}.", ""]
        lines += [f"![{name}]({p.as_posix()})" for p in figures[name] if "phase_diagram" in p.name] + [""]
    found = doubts(reports)
    lines += ["## What looks unconverged", ""]
    lines += [f"* {line}" for line in found] if found else ["Nothing was flagged."]
    lines += ["", "Flagged: unfinished or failed cases, undecided cases, PT/TU cases with fewer than "
              f"{MIN_GOOD_CYCLES} settled periods or a period uncertain by more than 0.5 %, and searches that "
              "did not converge.", ""]
    path.write_text("\n".join(lines) + "\n")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", choices=("coarse", "full"), default="coarse")
    parser.add_argument("--np", dest="np_", type=int, default=2, help="MPI ranks")
    parser.add_argument("--mpirun", default="mpirun", help="the mpirun command (with its environment)")
    parser.add_argument("--out", default="REPRODUCTION.md")
    parser.add_argument("--analyze-only", action="store_true", help="only analyze the existing campaign files")
    args = parser.parse_args(argv)
    jobs = {name: f"jobs/reproduce/{name}.toml" for name in COARSE} if args.grid == "coarse" else dict(FULL)
    hpcves = str(Path(sys.executable).with_name("hpcves"))
    walls = {name: 0.0 for name in jobs}
    if not args.analyze_only:
        walls = run_campaigns(jobs, shlex.split(args.mpirun), args.np_, hpcves,
                              Path("out/reproduce") / args.grid / "walls.json")
    for name, toml in jobs.items():       # a clear message if a campaign is missing
        read_source(load_study(toml).output)
    reports = analyse(jobs, Path("out/reproduce") / args.grid)
    figures = copy_figures(reports, FIGURES[args.grid])
    write_report(Path(args.out), args.grid, jobs, reports, figures, walls, args.np_)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
