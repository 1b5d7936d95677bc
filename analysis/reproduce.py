"""The reproduction study -> REPRODUCTION.md and docs/reproduction/ (``make reproduce``).

Runs the campaigns of jobs/reproduce/ (``--grid coarse``: a laptop, 2 cores) or
jobs/reproduce/fine/ (``--grid fine``: tighter tolerances, for a cluster) with
``mpirun -n NP hpcves campaign --resume``, so an interrupted reproduction
continues where it stopped; analyzes each with ``hpcves analyze`` and writes its
section of REPRODUCTION.md (docs/reproduction/sections/<campaign>.md: the
Markdown, after a comment line with what the run took and what looks
unconverged); then assembles REPRODUCTION.md from every section. ``--study
NAME,...`` (``make reproduce STUDY=...``) does this for some campaigns only and
keeps the other sections as they are, so no sitting has to hold the whole run.

The sections: theta(t) of the homogeneous vesicle and of psi_bar = 0.3, 0.5,
0.7; the TT and PT case pages; the period table; S_C against B2 and, with the
bending-energy gap, against psi_bar; the deflated cases of the publication's
Figs 8 and 9 and the refined phase diagrams (Delta x S at psi_bar = 0.48, S x
psi_bar at Delta = 0.94 and 2.3) with their boundaries, case pages and shape
sequences, each from the ellipse and from the authors' smoothed start; and a
list of everything that looks unconverged.
"""
from __future__ import annotations

import argparse
import datetime
import json
import math
import platform
import shlex
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import claims
from hpcves.analysis import accuracy, grids
from hpcves.campaign.file import read_table
from hpcves.campaign.progress import WORK_LEFT
from hpcves.campaign.study import load_study
from hpcves.model.params import LABELS
from hpcves.reports import attractor_map, case_pages
from hpcves.reports.analyze import (
    analyze,
    grid_use_of,
    pattern_cell,
    period_cell,
    read_source,
    regime_counts,
    run_labels,
)
from hpcves.reports.critical import critical_table
from hpcves.reports.refinement import superseded
from hpcves.reports.tables import markdown_table

JOBS = {"coarse": Path("jobs/reproduce"), "fine": Path("jobs/reproduce/fine")}
FIGURES = {"coarse": Path("docs/reproduction"), "fine": Path("docs/reproduction/fine")}
SECTION_DIRS = {grid: path / "sections" for grid, path in FIGURES.items()}
#: the studies whose case pages REPRODUCTION.md shows: every case gets its page, with streamlines (~3 s a
#: page); the other studies' pages are drawn for the flagged cases only (those "What looks unconverged"
#: lists), without streamlines (~1 s a page) -- a page for each of their ~1700 cases would take 22 min
FULL_PAGES = ("homogeneous", "periods", "psi048_cases", "psi048_cases_smoothed")
TARGET_HOURS = 3.0           # the wall time make reproduce (coarse) should take on 2 cores
STUDY_TARGET_HOURS = 1.0     # ... and any one of its studies (make reproduce STUDY=...)
MIN_GOOD_CYCLES = 5          # PT cases with fewer settled periods are flagged


def run_campaigns(jobs: dict, mpirun: list[str], np_: int, hpcves: str, ledger: Path,
                  retry_failed: bool = False) -> dict:
    """Run (or continue) every campaign; return its wall time in seconds in this call (0 if it was
    complete); ``retry_failed``: run its failed cases again too (``hpcves campaign --retry-failed``).
    The wall times of every call are added up in ``ledger`` (JSON), so that an interrupted
    and resumed reproduction still reports what all of it took.

    A campaign that ends with work left (``hpcves status``: exit status 3) stops the reproduction
    instead of letting the next one start: so does a SIGINT or SIGTERM, here (a SIGTERM is passed on
    to the campaign; it checkpoints its running cases, and its wall time so far is counted) or sent
    to the campaign's ranks only (Ctrl-C of a reproduction run in the background reaches them alone)."""
    walls = {}
    for name, toml in jobs.items():
        fresh = not Path(load_study(toml).output).exists()     # a new file: earlier calls ran another one
        start = time.monotonic()
        command = (mpirun + ["-n", str(np_), hpcves, "campaign", toml, "--resume", "--quiet"]
                   + (["--retry-failed"] if retry_failed else []))
        print(f"[{name}] {' '.join(command[-7 if retry_failed else -6:])}", flush=True)
        try:
            returncode, signalled = _run_forwarding_signals(command)
            left = (_work_left(hpcves, load_study(toml).output) if not signalled and returncode in (0, 1)
                    else None)               # a bad exit status or a signal stops it anyway
        finally:
            walls[name] = time.monotonic() - start
            _add_walls(ledger, {name: walls[name]}, restart=(name,) if fresh else ())
        if signalled:
            sys.exit(f"stopped by {signalled} during campaign {name} (its running cases checkpointed); "
                     "rerun make reproduce to continue")
        if returncode not in (0, 1):        # 1: some case failed -- reported in REPRODUCTION.md
            sys.exit(f"campaign {toml} stopped with exit status {returncode}; rerun make reproduce "
                     "to continue it")
        if left:
            sys.exit(f"campaign {toml} stopped before it was complete ({left}); rerun make reproduce to "
                     "continue it")
    return walls


def _run_forwarding_signals(command: list[str]) -> tuple[int, str | None]:
    """Run ``command`` and wait for it, also after a SIGINT or SIGTERM reaches this process: a
    SIGTERM is passed on to it (it checkpoints and exits); a SIGINT is not, since Ctrl-C reaches the
    whole foreground process group, the campaign's ranks included, and a second signal makes them
    give up at once. Returns (its exit status, the name of the signal that reached this process or
    None)."""
    child = subprocess.Popen(command)
    received = []

    def forward(signum, frame):
        received.append(signal.Signals(signum).name)
        if signum == signal.SIGTERM and child.poll() is None:
            child.send_signal(signum)

    handled = [s for s in (signal.SIGINT, signal.SIGTERM) if signal.getsignal(s) is not signal.SIG_IGN]
    previous = {s: signal.signal(s, forward) for s in handled}
    try:
        returncode = child.wait()
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    return returncode, (received[0] if received else None)


def _work_left(hpcves: str, output: str) -> str | None:
    """What ``hpcves status`` says is left in a campaign file (exit status 3), or None when complete."""
    result = subprocess.run([hpcves, "status", "--json", output], capture_output=True, text=True)
    if result.returncode != WORK_LEFT:
        return None
    try:
        return json.loads(result.stdout).get("left") or "work left"
    except json.JSONDecodeError:
        return "work left"


def _add_walls(ledger: Path, walls: dict, restart=()) -> dict:
    """Add ``walls`` (seconds per campaign) to the totals kept in ``ledger``; the totals. A campaign in
    ``restart`` made its file anew: its total starts again (the earlier calls ran a file since deleted)."""
    totals = json.loads(ledger.read_text()) if ledger.exists() else {}
    for name, wall in walls.items():
        totals[name] = (0.0 if name in restart else totals.get(name, 0.0)) + wall
    ledger.parent.mkdir(parents=True, exist_ok=True)
    ledger.write_text(json.dumps(totals, indent=1))
    return totals


def analyze_all(jobs: dict, out: Path, np_: int) -> dict:
    """Analyze every campaign into ``out/<name>``; draw the case pages (FULL_PAGES: every case's, the
    others: the flagged cases') in ``np_`` processes."""
    reports = {}
    for name, toml in jobs.items():
        study = load_study(toml)
        print(f"[{name}] analyze {study.output}", flush=True)
        report = analyze(study.output, out / name, case_figures="none")
        flagged = {case for case, _ in doubts({name: report}) if case is not None}
        damaged = {c.case_id for c in report.damaged}
        rows = [r for r in report.rows if (name in FULL_PAGES or r["case"] in flagged) and r["case"] not in damaged]
        directory = out / name / "cases"
        shutil.rmtree(directory, ignore_errors=True)           # no page left from an earlier analysis
        case_pages.draw_pages(report.source.path, True, rows, directory, streamlines=name in FULL_PAGES, jobs=np_)
        print(f"[{name}] {len(rows)} case pages in {directory}", flush=True)
        reports[name] = report
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


def prune_figures(report: Path, directory: Path) -> list[Path]:
    """Delete the PNG files directly in ``directory`` that ``report`` does not show (figures of an
    earlier version, figures analyze wrote that the report leaves out); the deleted paths."""
    text = report.read_text()
    stale = [p for p in sorted(directory.glob("*.png")) if f"({p.as_posix()})" not in text]
    for path in stale:
        path.unlink()
    return stale


def _fmt(value, spec=".4g") -> str:
    return format(value, spec) if isinstance(value, float) and math.isfinite(value) else ""


def _find(report, **values):
    """The regimes.csv row of ``report`` with these parameter values (None if there is none)."""
    for r in report.rows:
        if all(math.isclose(r[k], v, rel_tol=1e-9) for k, v in values.items()):
            return r
    return None


def period_table(report, rates=(80.0, 160.0, 320.0)) -> str:
    rows = report.rows
    psis = sorted({r["psi_bar"] for r in rows})
    body = []
    for psi in psis:
        line = [f"{psi:g}"]
        for s in rates:
            r = _find(report, psi_bar=psi, shear_rate=s)
            line.append(period_cell(r, " TU", f" (S T = {s * r['period']:.3g})" if r else ""))
        body.append(line)
    return markdown_table(["psi_bar \\ S"] + [f"{s:g}" for s in rates], body)


def theta_table(report) -> str:
    """S, regime and the settled inclination of every case (the homogeneous vesicle)."""
    body = []
    for r in sorted(report.rows, key=lambda r: r["shear_rate"]):
        error, dominant = accuracy.error_bar(r, "theta_mean")
        body.append([f"{r['shear_rate']:g}", r["regime"], _fmt(r["theta_mean"]),
                     f"{error:.1g} [{dominant}]" if math.isfinite(error) else "", _fmt(r["t_settle"])])
    return markdown_table(["S", "regime", "mean theta [rad]", "+-", "settled from t ="], body)


def theta_figure(report, directory: Path, name: str, group: str | None, title: str) -> Path:
    """theta(t) against S t for every case of ``report``, one panel per value of ``group``."""
    from hpcves.reports import diagrams

    cases = [c for c in report.source.cases if c.status != "damaged"]
    values = sorted({c.parameters[group] for c in cases}) if group else [None]
    panels = []
    for value in values:
        chosen = [c for c in cases if group is None or c.parameters[group] == value]
        label = title if group is None else f"{title}, {diagrams.parameter_text({group: value})}"
        panels.append((label, [(c.parameters["shear_rate"], c.series["t"], c.series["theta"]) for c in chosen]))
    fig = diagrams.theta_curves(panels)
    path = directory / f"{name}_theta.png"
    fig.savefig(path, dpi=110)
    return path


def copy_case_page(report, out: Path, directory: Path, name: str, **values) -> tuple[Path | None, dict | None]:
    """Copy the case page of the case with ``values`` into ``directory``: (its path, its row)."""
    row = _find(report, **values)
    if row is None:
        return None, None
    target = directory / f"{name}_case_{'_'.join(f'{k}{v:g}' for k, v in values.items())}.png"
    shutil.copyfile(out / name / "cases" / f"{row['case']}.png", target)
    return target, row


def shape_sequence(study_output: Path, directory: Path, name: str, rates=(1.0, 5.0, 20.0, 80.0)) -> Path | None:
    """Shapes over one settled period at psi_bar = 0.5 for the coarse shear rates of a refinement."""
    from hpcves.reports.figures import choose, shape_sequence_figure

    chosen = [c for c in choose(study_output, where={"psi_bar": 0.5})
              if any(math.isclose(c.parameters["shear_rate"], s, rel_tol=1e-9) for s in rates)]
    if not chosen:
        return None
    fig = shape_sequence_figure(chosen)
    path = directory / f"{name}_shapes_psi0.5.png"
    fig.savefig(path, dpi=100)
    return path


def refinement_text(out: Path, name: str) -> list[str]:
    """refinement.md of an analysed [refine] campaign, its headings moved down two levels."""
    text = (out / name / "refinement.md").read_text().strip().splitlines()
    return [("###" + line) if line.startswith("#") and not line.startswith("# ") else line
            for line in text[1:]]


def doubts(reports: dict) -> list[tuple[str | None, str]]:
    """Everything that looks unconverged or unresolved: (the case id or None, one line) each; a
    refinement's run that a later run of its point repeats is left out (the later one is the point's)."""
    lines = []
    for name, report in reports.items():
        repeated = superseded(report.source)
        for r in report.rows:
            if r["case"] in repeated:
                continue
            lam = r.get("viscosity_ratio", 1.0)
            label = (f"{name} case {r['case']} (S = {r['shear_rate']:g}, psi_bar = {r['psi_bar']:g}, "
                     f"Delta = {r['excess_length']:g}, B2 = {r['B2']:g}"
                     + (f", lambda = {lam:g})" if lam != 1 else ")"))
            line = None
            if r["status"] != "finished":
                line = f"{label}: {r['status']}: {r['reason']}"
            elif r["regime"] == "undecided":
                line = f"{label}: undecided -- {r['reason']}"
            elif r["regime"] in ("PT", "TU") and r["cycles"] < MIN_GOOD_CYCLES:
                line = f"{label}: {r['regime']} from only {r['cycles']:.1f} settled periods"
            elif r["regime"] in ("PT", "TU") and (bar := accuracy.error_bar(r, "period"))[0] > 0.005 * r["period"]:
                line = f"{label}: period uncertain by {bar[0] / r['period']:.1%} ({bar[1]} dominates)"
            if line is not None:
                lines.append((r["case"], line))
        for s in report.searches:
            if s["status"] != "converged":
                lines.append((None, f"{name}: search psi_bar = {s['psi_bar']:g}, B2 = {s['B2']:g}: {s['status']} "
                                    f"-- {s['reason']}"))
        for r in report.refinements:
            if r["status"] != "converged":
                lines.append((None, f"{name}: refinement {r['status']} -- {r['reason']}"))
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
    step = f"adaptive step, rtol = {num.rtol:g}" if num.adaptive else num.step_text()
    mode = ""
    if study.refine:
        settings = study.refine_settings
        tol = dict(study.refine.tolerance)
        mode = (f"; refined over {settings.x.key} x {settings.y.key} from a {len(settings.x.values)} x "
                f"{len(settings.y.values)} grid to {tol[settings.x.key]:g}" + (" (relative)" if settings.x.log else "")
                + f" and {tol[settings.y.key]:g}" + (" (relative)" if settings.y.log else "")
                + f", at most {study.refine.max_cases} cases")
    elif study.search:
        mode = (f"; {len(study.searches)} searches over S in [{study.search.low:g}, {study.search.high:g}] to "
                f"{study.search.rel_tol:g}")
    elif study.chain:
        mode = (f"; chains along {study.chain.along}" + (" there and back" if study.chain.back else "")
                + (f" from {len(study.starts)} starts" if study.starts else ""))
    return f"{num.grid()}, {step}, {end}, {sampling}{mode}"


def _images(paths) -> list[str]:
    return [f"![{p.stem}]({p.as_posix()})" for p in paths if p is not None] + [""]


# ---------------------------------------------------------------------------------------------------
# one section of REPRODUCTION.md per campaign
# ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Context:
    """What a section's writer reads: its campaign's report, the figures copied for it, where the
    analysis and the figures are, and its job file."""

    name: str
    report: object
    figures: list
    out: Path
    directory: Path
    toml: str
    grid: str = "coarse"

    @property
    def study(self):
        return load_study(self.toml)

    @property
    def start(self) -> str:
        """Which start the campaign's cases use, in words (SPEC section 7: a case says which)."""
        physics = self.study.base.physics
        if physics.initial_shape == "smoothed":
            return ("from the authors' smoothed start" if physics.psi_init_coordinate == "ellipse_parameter"
                    else "from the smoothed shape")
        return "from the ellipse"


def homogeneous_section(c: Context) -> list[str]:
    lines = ["## The homogeneous vesicle: theta(t) for S from 2 to 350 (Delta = 0.194)", "",
             "psi_bar = 0: one phase everywhere. theta(t) against the shear time S t, and the settled "
             "inclination:", ""]
    lines += _images([theta_figure(c.report, c.directory, c.name, None, r"$\bar\psi$ = 0")])
    return lines + [theta_table(c.report), ""]


def periods_section(c: Context) -> list[str]:
    lines = ["## theta(t) for psi_bar = 0.3, 0.5, 0.7 (Delta = 0.194)", ""]
    lines += _images([theta_figure(c.report, c.directory, c.name, "psi_bar", r"$\Delta$ = 0.194")])
    lines += ["### A tank-treading and a phase-treading case (psi_bar = 0.3, S = 40 and 80)", "",
              "Full case pages: theta, the energies and the centroid, the tension (min / mean / max), the "
              "phase velocities V_psi, V_L and V_psi + V_L over the settled window, the shapes coloured by psi "
              "with the streamlines around them (frame moving with the vesicle), tension and curvature "
              "kymographs.", ""]
    for shear in (40.0, 80.0):
        page, row = copy_case_page(c.report, c.out, c.directory, c.name, psi_bar=0.3, shear_rate=shear)
        if row is not None:
            lines += [f"S = {shear:g}: {row['regime']} -- {row['reason']}", ""] + _images([page])
    lines += ["### PT period at Delta = 0.194", "",
              "Period of theta +- its uncertainty; S T is the period in shear times (a 1/S law makes it "
              "constant).", "", period_table(c.report), ""]
    return lines + _images([p for p in c.figures if "periods" in p.name and "theta" not in p.name])


CRITICAL_NOTE = ("S_C lies in the final bracket [largest TT, smallest PT/TU], the result and its error bar; the "
                 "best estimate inside it extrapolates 1/T^2 of the two PT cases nearest above the bracket to zero "
                 "(a saddle-node's T ~ (S - S_C)^(-1/2); VALIDATION.md section 7 tests it), or is the bracket's "
                 "geometric centre where no two lie within 5 bracket widths or the root lands outside, as 'found "
                 "from' says. Delta E_b is the bending-energy gap (max - min of E_b over a "
                 "period) of the PT case at the bracket's top.")


def sc_b2_section(c: Context) -> list[str]:
    lines = ["## Critical shear rate against B2 at psi_bar = 0.3 (Delta = 0.194)", "", CRITICAL_NOTE, "",
             critical_table(list(c.report.searches), ["B2"]), ""]
    return lines + _images([p for p in c.figures if "critical" in p.name])


def sc_psi_section(c: Context) -> list[str]:
    lines = ["## Critical shear rate against psi_bar, with the bending-energy gap, at B2 = 0.1 and 0.8 "
             "(Delta = 0.194)", "", CRITICAL_NOTE, "", critical_table(list(c.report.searches), ["psi_bar", "B2"]), ""]
    return lines + _images([p for p in c.figures if "critical" in p.name]) + stress_lines(c)


def attractor_lines(c: Context, x_key: str, y_key: str) -> list[str]:
    """For a study from the authors' start: its points beside its twin's from the ellipse -- the map of
    where the two starts reach different attractors, and the count (hpcves/reports/attractor_map.py)."""
    twin = c.name.removesuffix("_smoothed")
    if twin == c.name:
        return []
    twin_output = load_study(JOBS[c.grid] / f"{twin}.toml").output
    heading = [f"### Attractor map: from the ellipse ({twin}) and from the authors' start", ""]
    if not Path(twin_output).exists():
        return heading + [f"Not drawn: the campaign file of {twin} is not on this machine (`make reproduce "
                          f"STUDY={twin},{c.name}` draws it).", ""]
    twin_rows = analyze(twin_output, c.out / twin, case_figures="none").rows
    compared = attractor_map.compare({"ellipse": twin_rows, "authors' start": c.report.rows}, values=False)
    starts = ("ellipse", "authors' start")
    fig = attractor_map.figure(compared, starts, x_key, y_key, f"{c.name}: the two starts point by point")
    path = c.directory / f"{c.name}_attractor_map.png"
    fig.savefig(path, dpi=100)
    return heading + ["Each point run from both starts is split between the regime reached from the ellipse "
                      "(left) and from the authors' start (right), and ringed where they reached different "
                      "attractors: another regime or another topology of the pattern (soft domains, how many on "
                      "the tips, two-fold symmetry). Not by theta or the period: the authors' start puts psi in "
                      "the ellipse's parameter, whose mean is psi_bar - 5e-4 at Delta = 0.94 and psi_bar - 9.3e-4 "
                      "at Delta = 2.3 (psi's mass is conserved), so the two starts' values are at slightly "
                      "different compositions.", "", attractor_map.summary(compared, starts), ""] + _images([path])


def cases_section(c: Context) -> list[str]:
    lines = [f"## The cases Delta = 0.94, S = 4 and Delta = 2.3, S = 28 (psi_bar = 0.48), {c.start}", "",
             "Run until decided (at most 1000 shear times), snapshots every 0.02; case pages with kymographs.", ""]
    for delta, shear in ((0.94, 4.0), (2.3, 28.0)):
        page, row = copy_case_page(c.report, c.out, c.directory, c.name, excess_length=delta, shear_rate=shear)
        if row is not None:
            lines += [f"Delta = {delta:g}, S = {shear:g}: {row['regime']} at t = {row['t']:.4g} -- "
                      f"{row['reason']}" + (f"; pattern: {pattern_cell(row)}" if pattern_cell(row) else ""),
                      ""] + _images([page])
    return lines + attractor_lines(c, "shear_rate", "excess_length")


def delta_s_section(c: Context) -> list[str]:
    return ([f"## Phase diagram Delta x S at psi_bar = 0.48 (refined), {c.start}", ""] + _phase_section(c)
            + attractor_lines(c, "shear_rate", "excess_length"))


def s_psi_section(c: Context) -> list[str]:
    delta = c.study.base.physics.excess_length
    lines = [f"## Phase diagram S x psi_bar at Delta = {delta:.2f} (refined), {c.start}", ""] + _phase_section(c)
    lines += ["Shapes over one settled period at psi_bar = 0.5 (the coarse shear rates):", ""]
    return (lines + _images([shape_sequence(c.study.output, c.directory, c.name)])
            + attractor_lines(c, "shear_rate", "psi_bar"))


def chain_section(c: Context) -> list[str]:
    """A continuation along S from two starts: the inclination and period along both legs, and the
    attractors of every S, told apart by regime and pattern topology (hpcves analyze: continuation.png;
    attractor_map.compare)."""
    physics = c.study.base.physics
    values = ", ".join(f"{v:g}" for v in c.study.sweep[c.study.chain.along])
    lines = [f"## Continuation along S at Delta = {physics.excess_length:g}, psi_bar = {physics.psi_bar:g}, "
             "from the ellipse and from the authors' start", "",
             f"S = {values} and back, each case starting from the settled end of the one before (its shape "
             "carried over, psi shifted to psi_bar; docs/analysis.md, \"Continuation\"), each chain once "
             "from the ellipse and once from the authors' smoothed start. Every case stops once decided.", ""]
    counts = ", ".join(f"{n} {r}" for r, n in c.report.counts().items())
    lines += [f"{len(c.report.rows)} cases: {counts}.", ""]
    lines += _images([p for p in c.figures if p.name.endswith("_continuation.png")])
    rows = list(c.report.rows)
    labels = run_labels(c.report.source, rows)
    names = tuple(dict.fromkeys(labels))
    compared = attractor_map.compare({n: [r for r, label in zip(rows, labels) if label == n] for n in names},
                                     values=False)
    lines += ["The runs of each S grouped into attractors by regime and pattern topology (soft domains, how many "
              "on the tips, two-fold symmetry), not by theta or the period: the first case from the authors' "
              "start has psi in the ellipse's parameter, whose mean is psi_bar - 9.3e-4 at Delta = 2.3, while "
              "every later case of its chain starts at psi_bar exactly (continuation.carried_start), so their "
              "periods differ by that composition (0.63797 against 0.63754 at S = 28 on 2026-12-05).", "",
              attractor_map.summary(compared, names), ""]
    body = [[f"{entry['shear_rate']:g}", "; ".join(a.text() for a in entry["attractors"])]
            for entry in sorted(compared, key=lambda e: e["shear_rate"])]
    lines += [markdown_table(["S", "attractors, and the runs that reached each"], body, left=(1,)), ""]
    return lines


def zero_crossings(S, values) -> list[float]:
    """Where ``values`` (against increasing ``S``) changes sign, by linear interpolation between neighbours."""
    return [s0 + (s1 - s0) * v0 / (v0 - v1) for s0, s1, v0, v1 in zip(S, S[1:], values, values[1:])
            if math.isfinite(v0) and math.isfinite(v1) and (v0 < 0) != (v1 < 0)]


def swinging_figure(rows: list[dict], directory: Path, name: str) -> Path:
    """The least settled theta against S: a point per case, by regime (TU: filled where theta flips,
    hollow where it swings without flipping), the line theta = 0 and the publication's S = 4."""
    import matplotlib.ticker
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 4.5), constrained_layout=True)
    ax = fig.subplots()
    ax.axhline(0.0, color="0.5", lw=1)
    ax.axvline(4.0, color="C3", ls="--", lw=1.2, label="the publication: tumbling for S < 4")
    ordered = sorted((r for r in rows if math.isfinite(r["theta_min"])), key=lambda r: r["shear_rate"])
    ax.plot([r["shear_rate"] for r in ordered], [r["theta_min"] for r in ordered], color="0.6", lw=1, zorder=1)
    def kind(r) -> str:
        """TU split by whether theta flips; PT and TT as they are; the rest together."""
        if r["regime"] == "TU":
            return "flips" if r.get("flips", 1) else "swings"
        return r["regime"] if r["regime"] in ("PT", "TT") else "other"

    styles = {"flips": ("o", "C0", "C0", "TU: theta flips (tumbling)"),
              "swings": ("o", "C0", "white", "TU: theta swings below 0, no flip"),
              "PT": ("s", "C1", "C1", "PT"), "TT": ("^", "C2", "C2", "TT"),
              "other": ("x", "k", "k", "undecided, failed")}
    for key, (marker, edge, face, label) in styles.items():
        chosen = [r for r in ordered if kind(r) == key]
        if chosen:
            ax.plot([r["shear_rate"] for r in chosen], [r["theta_min"] for r in chosen], marker, ms=8, mec=edge,
                    mfc=face, ls="", label=label, zorder=2)
    ax.set_xscale("log")
    ax.set_xticks([2, 3, 4, 5, 6, 8, 10, 12, 16])
    ax.xaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xlabel("shear rate $S$")
    ax.set_ylabel(r"least settled inclination min $\theta$ [rad]")
    ax.set_title(r"$\Delta$ = 2.3, $\bar\psi$ = 0.5, from the authors' start")
    ax.legend(frameon=False, fontsize=9)
    path = directory / f"{name}_theta_min.png"
    fig.savefig(path, dpi=110)
    return path


def swinging_section(c: Context) -> list[str]:
    rows = sorted(claims.points(c.report.rows), key=lambda r: r["shear_rate"])
    decided = [r for r in rows if r["regime"] in ("TT", "PT", "TU")]
    crossings = zero_crossings([r["shear_rate"] for r in decided], [r["theta_min"] for r in decided])
    swinging = [r for r in rows if r["regime"] == "TU" and r.get("flips") == 0]
    flipping = [r for r in rows if r["regime"] == "TU" and r.get("flips", 0) > 0]
    lines = ["## Swinging or tumbling: the least inclination against S (Delta = 2.3, psi_bar = 0.5)", "",
             f"{c.start.capitalize()}, the numerics of `jobs/reproduce/swinging.toml`. The publication calls "
             "this vesicle tumbling for S < 4, by its criterion min theta < 0 (its fig. 9b). A case is TU here by "
             "the same criterion; `flips` counts its settled passes through +-pi/2 -- a vesicle that turns over "
             "flips once a period, one that only swings below 0 and back never does (swinging: Noguchi & "
             "Gompper, PRL 98, 128103, 2007).", ""]
    lines += _images([swinging_figure(rows, c.directory, c.name)])
    body = [[f"{r['shear_rate']:g}", r["regime"], _fmt(r["theta_min"]),
             _fmt(r.get("flips", math.nan), ".0f") if r["regime"] == "TU" else "", _fmt(r["period"]),
             r["reason"]] for r in rows]
    lines += [markdown_table(["S", "regime", "min theta [rad]", "flips", "period", "reason"], body,
                             left=(1, 5)), ""]
    where = ", ".join(f"{s:.3g}" for s in crossings) or "nowhere in the range"
    zero = [r for r in rows if math.isfinite(r["theta_min"]) and abs(r["theta_min"]) < 1e-12]
    last_flip = max((r["shear_rate"] for r in flipping), default=math.nan)
    first_swing = min((r["shear_rate"] for r in swinging), default=math.nan)
    lines += [f"min theta crosses 0 at S = {where} (linear between neighbouring decided cases), against the "
              "publication's 4" + (" (at S = " + ", ".join(f"{r['shear_rate']:g}" for r in zero)
                                   + " min theta is 0 to round-off, so which side of 0 it lies on means nothing)"
                                   if zero else "")
              + (f"; the vesicle turns over up to S = {last_flip:g} and only swings from S = {first_swing:g} on, so "
                 f"the flips end between {last_flip:g} and {first_swing:g}"
                 if math.isfinite(last_flip) and math.isfinite(first_swing) else "") + ". "
              f"Of the TU cases, {len(flipping)} flip and {len(swinging)} swing without "
              "flipping" + (" (S = " + ", ".join(f"{r['shear_rate']:g}" for r in swinging) + ")" if swinging
                            else "") + ".", ""]
    return lines


@dataclass(frozen=True)
class DisputedPoints:
    """A campaign of points where hpcves and the publication differ, run in the publication's numerics
    (``preset = "publication"``; its twin ``<name>_default`` in hpcves's): what to call it, the plane, and
    what the publication says there, with the regime it gives every point."""

    title: str
    y_key: str
    says: str
    regime: str
    short: str          # the figure's title


DISPUTED = {
    "publication_mode": DisputedPoints(
        "The disputed Fig. 9b points (Delta = 2.3)", "psi_bar",
        "phase-treading for psi_bar in 0.44-0.58 (fig. 9b), with S_C = 120 at psi_bar = 0.44: PT at S = 40 and at "
        "160 there", "PT", "Fig. 9b, Delta = 2.3"),
    "publication_mode_fig7a": DisputedPoints(
        "The disputed Fig. 7a points (psi_bar = 0.48)", "excess_length",
        "no tank-treading for Delta > 1.6, phase-treading for S > 15 and Delta < 3 (fig. 7a): PT at every point "
        "here", "PT", "Fig. 7a, psi_bar = 0.48"),
}


def _numerics_table(rows_by_numerics: dict, y_key: str) -> list[str]:
    """A row per point: what each numerics reached there (regime, mean theta or period, the pattern)."""
    points = sorted({(r["shear_rate"], r[y_key]) for rows in rows_by_numerics.values() for r in rows})
    head = ["S", y_key] + [f"{name}: {what}" for name in rows_by_numerics for what in ("regime", "theta / period")]
    body = []
    for shear, y in points:
        cells = [f"{shear:g}", f"{y:g}"]
        for rows in rows_by_numerics.values():
            row = next((r for r in rows if (r["shear_rate"], r[y_key]) == (shear, y)), None)
            if row is None:
                cells += ["not run", ""]
                continue
            value = (f"T = {_fmt(row['period'])}" if row["regime"] in ("PT", "TU") else
                     f"{_fmt(row['theta_mean'])} rad" if math.isfinite(row["theta_mean"]) else "")
            cells += [row["regime"] + (f" ({pattern_cell(row)})" if pattern_cell(row) else ""), value]
        body.append(cells)
    return [markdown_table(head, body, left=tuple(range(2, len(head)))), ""]


def publication_mode_default_section(c: Context) -> list[str]:
    disputed = DISPUTED[c.name.removesuffix("_default")]
    return [f"## {disputed.title} in hpcves's numerics (the linear law, the authors' start)", "",
            "The twin of the next section: the same physics in hpcves's converged numerics (adaptive SBDF2, "
            "rtol = 1e-3, N adapting, rates on 2 N nodes).", ""] + _numerics_table(
                {"hpcves": claims.points(c.report.rows)}, disputed.y_key)


def publication_mode_section(c: Context) -> list[str]:
    disputed, twin = DISPUTED[c.name], f"{c.name}_default"
    y_key = disputed.y_key
    twin_output = load_study(JOBS[c.grid] / f"{twin}.toml").output
    rows = claims.points(c.report.rows)
    lines = [f"## {disputed.title} in the publication's numerics (`preset = \"publication\"`)", "",
             "The authors' time integration as their code takes it (integrating factor and Adams-Bashforth for "
             "the shape, 20 substeps of the phase field with the shape frozen), fixed dt = 1e-5, their filter, "
             f"the linear law and their start, N = {c.study.base.numerics.N} (docs/numerics.md, \"The publication's "
             "scheme\": checked against the authors' code under Octave). The publication: " + disputed.says + ".", ""]
    if not Path(twin_output).exists():
        return lines + _numerics_table({"publication's numerics": rows}, y_key) + [
            f"Not compared: the campaign file of {twin} is not on this machine (`make reproduce "
            f"STUDY={twin},{c.name}` draws it).", ""]
    twin_rows = analyze(twin_output, c.out / twin, case_figures="none").rows
    twin_points = claims.points(twin_rows)
    lines += _numerics_table({"hpcves's numerics": twin_points, "publication's numerics": rows}, y_key)
    names = ("hpcves's numerics", "publication's numerics")
    compared = attractor_map.compare({names[0]: twin_rows, names[1]: c.report.rows}, values=False)
    fig = attractor_map.figure(compared, names, "shear_rate", y_key,
                               f"{disputed.short}: the two numerics point by point")
    path = c.directory / f"{c.name}_attractor_map.png"
    fig.savefig(path, dpi=100)
    named = [r for r in rows if r["regime"] == disputed.regime]
    twin_at = {(r["shear_rate"], r[y_key]): r for r in twin_points}
    creeping = [r for r in rows if r["regime"] == "undecided" and math.isfinite(r.get("pattern_speed", math.nan))
                and math.isfinite(r["theta_mean"])]
    if creeping:
        gaps = [abs(r["theta_mean"] - t["theta_mean"]) for r in creeping
                if (t := twin_at.get((r["shear_rate"], r[y_key]))) is not None and t["regime"] == "TT"]
        speeds = [abs(r["pattern_speed"]) for r in creeping]
        moving = [abs(r["pattern_speed"]) for r in rows
                  if r["regime"] == "PT" and math.isfinite(r.get("pattern_speed", math.nan))]
        lines += [f"{len(creeping)} points stay undecided in the publication's numerics: theta is steady"
                  + (f" (within {max(gaps):.1g} rad of hpcves's TT there)" if gaps else "")
                  + f" while the pattern creeps through the lab frame at {min(speeds):.2g}-{max(speeds):.2g} of "
                  "the tank-treading speed" + (f", where phase-treading moves at {min(moving):.2g}-{max(moving):.2g}"
                                               if moving else "")
                  + ". That is not phase-treading; the runs (to t_end) do not tell whether the creep is the "
                  "first-order scheme's or a slow drift towards another state.", ""]
    return lines + ["Each point split between the regime in hpcves's numerics (left) and in the publication's "
                    "(right), ringed where they reached different attractors (regime or pattern topology).", "",
                    attractor_map.summary(compared, names), "",
                    f"In the publication's numerics {len(named)} of {len(rows)} points are {disputed.regime}"
                    + (" (" + ", ".join(f"S = {r['shear_rate']:g}, {y_key} = {r[y_key]:g}" for r in named) + ")"
                       if named else "") + f"; the publication has {disputed.regime} at all of them.", ""] \
        + _images([path])


def _phase_section(c: Context) -> list[str]:
    repeated = superseded(c.report.source)
    latest = [r for r in c.report.rows if r["case"] not in repeated]
    counts = ", ".join(f"{n} {r}" for r, n in regime_counts(latest).items())
    lines = [f"{len(c.report.rows)} cases: {counts}." if not repeated else
             f"{len(c.report.rows)} cases, {len(latest)} points: {counts} (the point's last run where a refinement "
             f"ran {len(repeated)} again).", ""]
    lines += _images([p for p in c.figures if "phase_diagram" in p.name])
    return lines + refinement_text(c.out, c.name) + [""] + stress_lines(c)


def _spread(values: list[float]) -> str:
    return f"{min(values):.4g}-{max(values):.4g} (median {float(np.median(values)):.4g})"


def stress_lines(c: Context) -> list[str]:
    """Beyond the publication: the stress the vesicles add (issue 66) -- [eta] and N1 of the settled cases by
    regime, where the extremes lie, and the maps analyze drew; for a campaign file made before the rheology
    series (case format 7), how to get them."""
    repeated = superseded(c.report.source)
    rows = [r for r in c.report.rows if r["case"] not in repeated]
    have = [r for r in rows if math.isfinite(r.get("intrinsic_viscosity", math.nan))]
    lines = ["### Beyond the publication: the stress the vesicles add", ""]
    if not have:
        return lines + [f"Its campaign file predates the rheology series (case format 7, issue 66): move "
                        f"`{c.study.output}` away and `make reproduce STUDY={c.name}` runs it again with them "
                        "(docs/numerics.md, \"Rheology\").", ""]
    by_regime = {}
    for r in have:
        by_regime.setdefault(r["regime"], []).append(r)
    parts = [f"{regime} ({len(group)}): [eta] {_spread([r['intrinsic_viscosity'] for r in group])}, N1 "
             f"{_spread([r['normal_stress_coefficient'] for r in group])}" for regime, group in by_regime.items()]
    keys = [k for k in ("shear_rate", "psi_bar", "excess_length", "viscosity_ratio") if len({r[k] for r in rows}) > 1]

    def where(r):
        return ", ".join(f"{LABELS.get(k, k)} = {r[k]:.4g}" for k in keys)

    low, high = min(have, key=lambda r: r["intrinsic_viscosity"]), max(have, key=lambda r: r["intrinsic_viscosity"])
    bars = [accuracy.error_bar(r, "intrinsic_viscosity")[0] for r in have]
    lines += [f"The intrinsic viscosity [eta] = Sigma_xy / (S A) and first normal-stress coefficient N1 = "
              f"(Sigma_xx - Sigma_yy) / (S A) of the {len(have)} settled cases (a dilute suspension's viscosity is "
              f"eta (1 + [eta] phi); the rigid disk has [eta] = 2, N1 = 0), by regime: " + "; ".join(parts) + ". "
              f"Least [eta] {low['intrinsic_viscosity']:.4g} ({low['regime']}, {where(low)}), largest "
              f"{high['intrinsic_viscosity']:.4g} ({high['regime']}, {where(high)}); each mean's whole error bar is "
              f"at most {max(bars):.1g} (median {float(np.median(bars)):.1g}; n/e parts left out: "
              "regimes.csv has each).", ""]
    jumps = stress_jumps(have, [k for k in keys if k != "shear_rate"]) if "shear_rate" in keys else []
    if jumps:
        lines[-2] += (f" Along S, where a tank-treading case is followed by a phase-treading or tumbling one "
                      f"({len(jumps)} such neighbours), [eta] changes across the transition by "
                      f"{min(jumps):+.2%} to {max(jumps):+.2%} (median {float(np.median(jumps)):+.2%}).")
    return lines + _images([p for p in c.figures if "intrinsic_viscosity" in p.stem or "normal_stress" in p.stem])


def stress_jumps(rows: list[dict], others: list[str]) -> list[float]:
    """The relative change of [eta] from a TT case to the next case along S (same other parameters) where that
    one is PT or TU: what the transition does to the suspension's viscosity."""
    lines = {}
    for r in rows:
        lines.setdefault(tuple(r[k] for k in others), []).append(r)
    out = []
    for line in lines.values():
        line.sort(key=lambda r: r["shear_rate"])
        out += [b["intrinsic_viscosity"] / a["intrinsic_viscosity"] - 1 for a, b in zip(line, line[1:])
                if a["regime"] == "TT" and b["regime"] in ("PT", "TU")]
    return out


GERA = ("Gera, Salac & Spagnolie (J. Fluid Mech. 2022; arXiv:2108.10671) give a small-deformation theory of a "
        "two-dimensional vesicle whose bending stiffness varies along the membrane and moves with it: a membrane "
        "of nearly uniform stiffness swings (theta oscillates without flipping while the membrane tank-treads -- "
        "what this model calls phase-treading, PT, as its stiff and soft domains tank-tread with the membrane), "
        "and a variation beyond a critical size, relative to the flow rate and to the viscosity contrast, makes "
        "it tumble (TU). Their sequence is swinging where the flow is strong and tumbling where the stiffness "
        "variation outweighs it, the threshold moving with lambda. Their domains cannot slip through the "
        "membrane, so the TT of this model (a pattern held fixed in the lab frame by diffusion while the "
        "membrane tank-treads) has no counterpart there; and their shapes are nearly circles (Delta = 0.194 "
        "is close to one, 0.94 is not)")


def _runs(pairs) -> str:
    """'PT (0.1 - 2.5) -> TU (12.5 - 62.5)': the regimes along an axis, consecutive equal ones merged."""
    merged = []
    for value, regime in pairs:
        if merged and merged[-1][0] == regime:
            merged[-1][2] = value
        else:
            merged.append([regime, value, value])
    return " -> ".join(f"{r} ({a:g})" if a == b else f"{r} ({a:g} - {b:g})" for r, a, b in merged)


def contrast_section(c: Context) -> list[str]:
    """A lambda x S or lambda x psi_bar diagram of the two-phase vesicle (issue #42): the refined diagram,
    the regime sequence along lambda at every coarse value of the other axis (and along S at every coarse
    lambda), and how that sequence compares with Gera, Salac & Spagnolie's."""
    study, physics = c.study, c.study.base.physics
    other = next(k for k in study.refine.axes if k != "viscosity_ratio")
    if other == "shear_rate":
        title = (f"## Beyond the publication: lambda x S at psi_bar = {physics.psi_bar:g}, "
                 f"Delta = {physics.excess_length:.3g} (refined)")
    else:
        title = (f"## Beyond the publication: lambda x psi_bar at Delta = {physics.excess_length:.3g}, "
                 f"S = {physics.shear_rate:g} (refined)")
    lines = [title, "", "The viscosity ratio lambda = eta_in / eta_out (`physics.viscosity_ratio`; the publication "
             "has lambda = 1 throughout and names the interplay of a contrast with the inhomogeneous bending as "
             "open). From the ellipse.", ""] + _phase_section(c)
    repeated = superseded(c.report.source)
    rows = [r for r in c.report.rows if r["case"] not in repeated]
    decided = ("TT", "PT", "TU")
    sequences = []
    for value in study.sweep[other]:
        pairs = sorted((r["viscosity_ratio"], r["regime"]) for r in rows if r[other] == value)
        sequences.append(f"{LABELS.get(other, other)} = {value:g}: " + _runs(pairs))
    lines += ["Along lambda at each coarse value of the other axis (every case on that line, refined ones "
              "included):", ""] + [f"* {line}" for line in sequences] + [""]
    # the ordering a swinging -> tumbling picture asks for: along lambda, nothing but TU above a TU
    against = []
    for value in sorted({r[other] for r in rows}):
        line = sorted((r["viscosity_ratio"], r["regime"]) for r in rows if r[other] == value and r["regime"] in decided)
        first_tu = next((lam for lam, regime in line if regime == "TU"), None)
        if first_tu is not None:
            against += [f"{other} = {value:g}, lambda = {lam:g}: {regime} above TU at lambda = {first_tu:g}"
                        for lam, regime in line if lam > first_tu and regime != "TU"]
    lines += [GERA + ".", "",
              "Tumbling here is reached by raising lambda: along every line of constant "
              f"{LABELS.get(other, other)} in the file, "
              + ("no decided case above the first tumbling one is anything but TU" if not against else
                 f"{len(against)} decided cases above a tumbling one are not TU: " + "; ".join(against[:6])
                 + ("; ..." if len(against) > 6 else ""))
              + "."]
    if other == "shear_rate":
        below = []
        for lam in sorted({r["viscosity_ratio"] for r in rows}):
            line = sorted((r["shear_rate"], r["regime"]) for r in rows
                          if r["viscosity_ratio"] == lam and r["regime"] in decided)
            last_tu = max((s for s, regime in line if regime == "TU"), default=None)
            if last_tu is not None:
                below += [f"lambda = {lam:g}, S = {s:g}: PT below TU at S = {last_tu:g}"
                          for s, regime in line if s < last_tu and regime == "PT"]
        lines[-1] += (" Along S at fixed lambda the vesicle tumbles where the flow is weak and phase-treads "
                      "(swings) where it is strong: "
                      + ("no phase-treading case lies below a tumbling one" if not below else
                         f"{len(below)} phase-treading cases lie below a tumbling one: " + "; ".join(below[:6])
                         + ("; ..." if len(below) > 6 else "")) + ".")
    swinging = [r for r in rows if r["regime"] == "undecided" and "theta oscillates" in r["reason"]
                and "fixed" in r["reason"]]
    lines += ["", ("No case swings with its pattern fixed in the lab frame (theta oscillating without flipping "
                   "while the pattern stays put: the classifier would leave such a case undecided and say so)."
                   if not swinging else
                   f"{len(swinging)} cases oscillate without flipping while the pattern stays fixed in the lab "
                   f"frame (swinging without phase-treading): {', '.join(r['case'] for r in swinging[:10])}."), ""]
    return lines


#: every campaign of the reproduction, in the order of REPRODUCTION.md, and the writer of its section
SECTIONS = {
    "homogeneous": homogeneous_section,
    "periods": periods_section,
    "sc_b2": sc_b2_section,
    "sc_psi": sc_psi_section,
    "psi048_cases": cases_section,
    "psi048_cases_smoothed": cases_section,
    "psi048_delta_S": delta_s_section,
    "psi048_delta_S_smoothed": delta_s_section,
    "delta094_S_psi": s_psi_section,
    "delta094_S_psi_smoothed": s_psi_section,
    "delta230_S_psi": s_psi_section,
    "delta230_S_psi_smoothed": s_psi_section,
    "delta230_chain": chain_section,
    "swinging": swinging_section,
    "publication_mode_default": publication_mode_default_section,
    "publication_mode": publication_mode_section,
    "publication_mode_fig7a_default": publication_mode_default_section,
    "publication_mode_fig7a": publication_mode_section,
    "contrast_lambda_S_D0194": contrast_section,
    "contrast_lambda_S_D094": contrast_section,
    "contrast_lambda_psi": contrast_section,
}
STUDIES = tuple(SECTIONS)
SECTION_TAG = "<!-- hpcves reproduce section "


def write_section(path: Path, lines: list[str], meta: dict) -> None:
    """One section: a comment line with what was measured (JSON), then its Markdown."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(SECTION_TAG + json.dumps(meta, sort_keys=True) + " -->\n" + "\n".join(lines).rstrip() + "\n")


def read_section(path: Path) -> tuple[dict, str] | None:
    """(what was measured, the Markdown) of a section file, or None if there is none."""
    if not path.exists():
        return None
    first, _, body = path.read_text().partition("\n")
    if not first.startswith(SECTION_TAG):
        raise SystemExit(f"{path}: not a section of the reproduction (no '{SECTION_TAG.strip()}' line)")
    return json.loads(first[len(SECTION_TAG):].removesuffix("-->").strip()), body


def write_study_section(grid: str, name: str, toml: str, out: Path, np_: int, totals: dict,
                        ranks: int | None = None) -> None:
    """Analyze one campaign, copy its figures and write its section, with what it took."""
    start = time.monotonic()
    report = analyze_all({name: toml}, out, np_)[name]
    figures = copy_figures({name: report}, FIGURES[grid])[name]
    lines = SECTIONS[name](Context(name, report, figures, out, FIGURES[grid], toml, grid))
    rows = read_table(load_study(toml).output).rows
    meta = {"study": name, "job": toml, "written": str(datetime.date.today()), "machine": platform.node(),
            "processor": platform.processor() or platform.machine(), "ranks": ranks or np_,
            "numerics": numerics_line(toml), "cases": len(report.rows),
            "grids": grids.use_text(use) if len(use := grid_use_of(report.source)) > 1 else "",
            "compute_s": round(sum(row["wall"] for row in rows), 1),
            "campaign_wall_s": round(totals[name], 1) if name in totals else None,
            "analysis_wall_s": round(time.monotonic() - start, 1),
            "pages": len(list((out / name / "cases").glob("*.png"))),
            "doubts": [line for _, line in doubts({name: report})], "claims": claims.measure(name, report)}
    write_section(SECTION_DIRS[grid] / f"{name}.md", lines, meta)
    print(f"[{name}] section {SECTION_DIRS[grid] / name}.md", flush=True)


def _minutes(seconds) -> str:
    return "not recorded" if seconds is None else f"{seconds / 60:.1f} min"


def _campaign_minutes(seconds) -> str:
    over = seconds is not None and seconds > 3600 * STUDY_TARGET_HOURS
    return _minutes(seconds) + (f" (over the {STUDY_TARGET_HOURS:g} h a study should take)" if over else "")


def assemble(path: Path, grid: str) -> None:
    """REPRODUCTION.md from the section of every study (a study without one is listed as not run)."""
    found = {name: read_section(SECTION_DIRS[grid] / f"{name}.md") for name in STUDIES}
    present = {name: section for name, section in found.items() if section is not None}
    metas = [meta for meta, _ in present.values()]
    campaign = sum(m["campaign_wall_s"] or 0.0 for m in metas)
    analysis = sum(m["analysis_wall_s"] or 0.0 for m in metas)
    unrecorded = [m["study"] for m in metas if m["campaign_wall_s"] is None or m["analysis_wall_s"] is None]
    lines = [
        "# Reproduction of the published studies (`make reproduce`)", "",
        f"Assembled by `analysis/reproduce.py --grid {grid}` on {datetime.date.today()} from one section per "
        "campaign, each written when its campaign was last analysed: `make reproduce STUDY=name` reruns (or "
        "continues) one campaign and rewrites its section, `make reproduce` does all of them. "
        f"**Wall time: {(campaign + analysis) / 3600:.2f} h in all** (target for the coarse set on 2 cores: "
        f"{TARGET_HOURS:g} h, and at most ~{STUDY_TARGET_HOURS:g} h for any one study): the campaigns "
        f"{campaign / 3600:.2f} h (every call that advanced them added up), their analysis (tables, figures, "
        f"case pages) {analysis / 60:.0f} min"
        + (f"; not recorded for {', '.join(unrecorded)}" if unrecorded else "") + ".", "",
        markdown_table(["campaign", "numerics", "cases", "core-min", "campaign wall", "analysis", "written"],
                       [[f"`{m['job']}`", m["numerics"] + (f"; grids: {m['grids']}" if m.get("grids") else ""),
                         str(m["cases"]), f"{m['compute_s'] / 60:.1f}",
                         _campaign_minutes(m["campaign_wall_s"]), _minutes(m["analysis_wall_s"]),
                         f"{m['written']} ({m['machine']}, {m['ranks']} ranks)"] for m in metas]),
        ""]
    notes = list(dict.fromkeys(note for m in metas for note in m.get("notes", [])))
    lines += [f"Note: {note}." for note in notes] + ([""] if notes else [])
    missing = [name for name in STUDIES if name not in present]
    if missing:
        lines += [f"Not run yet: {', '.join(missing)} (`make reproduce STUDY={','.join(missing)}`).", ""]
    lines += ["## The publication's claims beside hpcves", "",
              "Every claim of the publication's results sections, where it makes it (the label in "
              "publication.tex), and what the campaigns of this reproduction find (analysis/claims.py says how "
              "each is measured: a region of a diagram by its decided cases, **agrees** from 90 % with the "
              "regime it names, **mostly** from 50 %). The publication's runs used dt = 1e-5 and an ellipse "
              "smoothed by their code, which also filters the top modes of its tangent-angle equation every "
              "step (hpcves does not: on sharp deflated shapes that filter moves tumbling periods by up to 5 %, "
              "docs/numerics.md, \"Stalled runs\"); where they differ from ours, the sections below and "
              "docs/numerics.md (\"Initial shape\", \"Resolution of deflated shapes\") give the start and the "
              "convergence evidence.", "",
              markdown_table(["where", "the publication", "hpcves from the ellipse", "hpcves from the authors' start",
                              "where they differ: why"],
                             claims.table({name: meta.get("claims") for name, (meta, _) in present.items()}),
                             left=(0, 1, 2, 3, 4)),
              ""]
    lines += ["Regimes are decided by `hpcves analyze` (docs/analysis.md) with its default thresholds; "
              f"the tables and figures of each campaign are in `out/reproduce/{grid}/<campaign>/` (case pages: see "
              "the end). Error bars: the statistical uncertainty plus the discretisation error of the time step "
              "(docs/error_rule.md); in brackets the part that dominates. The deflated studies run from two "
              "starts (docs/numerics.md, \"Initial shape\"): the ellipse the publication states, and the "
              "smoothed shape its authors' code started from; each section says which. What mapping both "
              "starts costs against one, and what a cheaper scheme would miss: docs/attractor_cost.md "
              "(analysis/attractor_cost.py).", ""]
    for _, body in present.values():
        lines += [body.rstrip(), ""]
    flagged = [line for m in metas for line in m["doubts"]]
    lines += ["## What looks unconverged", ""]
    lines += [f"* {line}" for line in flagged] if flagged else ["Nothing was flagged."]
    lines += ["", "Flagged: unfinished or failed cases, undecided cases, PT/TU cases with fewer than "
              f"{MIN_GOOD_CYCLES} settled periods or a period uncertain by more than 0.5 %, searches and "
              "refinements that did not converge. Every flagged case has its page in "
              f"`out/reproduce/{grid}/<campaign>/cases/<case>.png` (as have all cases of "
              f"{', '.join(FULL_PAGES)}); `hpcves analyze FILE` draws every case's page.", ""]
    path.write_text("\n".join(lines))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", choices=tuple(JOBS), default="coarse")
    parser.add_argument("--np", dest="np_", type=int, default=2, help="MPI ranks")
    parser.add_argument("--mpirun", default="mpirun", help="the mpirun command (with its environment)")
    parser.add_argument("--out", default="REPRODUCTION.md")
    parser.add_argument("--study", metavar="NAME,...",
                        help=f"only these campaigns: run, analyze, rewrite their sections; any of {', '.join(STUDIES)}")
    parser.add_argument("--analyze-only", action="store_true", help="only analyze the existing campaign files")
    parser.add_argument("--retry-failed", action="store_true",
                        help="run the failed cases of the campaigns again (hpcves campaign --retry-failed)")
    parser.add_argument("--assemble-only", action="store_true", help="only assemble the report from the sections")
    parser.add_argument("--only", metavar="NAME,...",
                        help="run (or continue) only these campaigns and stop (no analysis)")
    args = parser.parse_args(argv)
    jobs = {name: (JOBS[args.grid] / f"{name}.toml").as_posix() for name in STUDIES}
    names = list(STUDIES)
    for option in ("study", "only"):
        if getattr(args, option):
            names = getattr(args, option).split(",")
            unknown = [n for n in names if n not in jobs]
            if unknown:
                parser.error(f"--{option}: no campaign {', '.join(unknown)} (there are {', '.join(STUDIES)})")
    hpcves = str(Path(sys.executable).with_name("hpcves"))
    out = Path("out/reproduce") / args.grid
    ledger = out / "walls.json"
    if args.only:
        run_campaigns({n: jobs[n] for n in names}, shlex.split(args.mpirun), args.np_, hpcves, ledger,
                          args.retry_failed)
        print(f"{', '.join(names)}: run as far as this call went (stopped ones continue when rerun); "
              f"make reproduce STUDY={','.join(names)} analyzes them into {args.out}")
        return
    if not args.assemble_only:
        if not args.analyze_only:
            run_campaigns({n: jobs[n] for n in names}, shlex.split(args.mpirun), args.np_, hpcves, ledger,
                          args.retry_failed)
        totals = json.loads(ledger.read_text()) if ledger.exists() else {}
        for name in names:                 # a clear message if a campaign is missing
            read_source(load_study(jobs[name]).output)
        for name in names:
            ranks = args.np_
            if args.analyze_only:              # the campaign's ranks are those of the run that wrote its section
                kept = read_section(SECTION_DIRS[args.grid] / f"{name}.md")
                ranks = kept[0].get("ranks", ranks) if kept else ranks
            write_study_section(args.grid, name, jobs[name], out, args.np_, totals, ranks)
    assemble(Path(args.out), args.grid)
    stale = prune_figures(Path(args.out), FIGURES[args.grid])
    print(f"wrote {args.out}" + (f"; removed {len(stale)} figures from {FIGURES[args.grid]} it does not show"
                                  if stale else ""))


if __name__ == "__main__":
    main()
