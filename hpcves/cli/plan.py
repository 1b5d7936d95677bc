"""``hpcves campaign --plan``: what a study will cost (cases, core-hours, ranks, wall time) and a SLURM
batch script sized from it; nothing runs but the timing of a step."""
from __future__ import annotations

import math
import os
import shutil
import signal
import sys
from pathlib import Path

import click

from hpcves.campaign.plan import DECIDED_AFTER, memory_per_rank, plan
from hpcves.campaign.queue import computing_ranks, ranks_for
from hpcves.campaign.slurm import JobSize, mem_per_cpu, read_template, refuse_unsafe_paths, slurm_script
from hpcves.campaign.slurm import max_jobs as default_max_jobs
from hpcves.campaign.structure import file_bytes
from hpcves.campaign.study import load_study
from hpcves.cli.terminal import SigtermSeen, clean_errors, duration, fail, os_error_text
from hpcves.errors import HpcvesError
from hpcves.files import atomic
from hpcves.files.atomic import check_output_path, size_text
from hpcves.reports.tables import markdown_table
from hpcves.run.timing import StepCost, classify_seconds, layout_seconds


@clean_errors
def print_plan(study_file, out, slurm_file, max_time, slurm_template=None, max_jobs=None) -> None:
    """``hpcves campaign --plan``: what the study will cost, and a batch script sized from it."""

    try:
        study = load_study(study_file)
    except HpcvesError as exc:
        fail(str(exc))
    if not max_time > 0:
        fail(f"--max-time {max_time:g}: must be > 0 hours")
    if slurm_file:
        check_output_path(slurm_file)
        if not Path(slurm_file).absolute().parent.is_dir():        # say so before the timing, not after
            fail(f"{slurm_file}: its directory {Path(slurm_file).absolute().parent} does not exist")
        try:
            template = read_template(slurm_template)         # refused now, not after the timing
        except HpcvesError as exc:
            fail(str(exc))
        if max_jobs is not None and max_jobs < 1:
            fail(f"--max-jobs {max_jobs}: must be at least 1")
        try:                                                  # before the timing, as the rest
            refuse_unsafe_paths(script=Path(slurm_file), study_file=Path(study_file),
                                output=Path(out or study.output), hpcves=_hpcves(), python=Path(sys.executable),
                                workdir=Path.cwd())
        except HpcvesError as exc:
            fail(str(exc))
    # a step is timed in a scratch directory, removed when the timing ends; SIGTERM (a batch system,
    # `timeout`) would kill the process before that: noted instead, the timing runs stop at their next
    # step, the directory is removed, and the command exits with 128 + 15
    sigterm = SigtermSeen()
    previous = signal.signal(signal.SIGTERM, sigterm)
    try:
        estimate = plan(study, StepCost(announce=lambda text: click.echo(text, err=True), stop_requested=sigterm.seen),
                        layout_seconds, classify_seconds)
    finally:
        signal.signal(signal.SIGTERM, previous)
    if sigterm.seen():
        raise SystemExit(128 + signal.SIGTERM)
    basis = estimate.likely or estimate              # what the run will likely take: ranks and time from it
    ranks = basis.suggested_ranks()
    wall = basis.wall(ranks)
    ask = min(_job_seconds(wall), max_time * 3600.0)
    path = Path(out or study.output).absolute()
    click.echo(_plan_text(estimate, study, ranks))
    click.echo(f"suggested: {ranks} rank{'s' * (ranks != 1)} (srun -n {ranks} / mpirun -n {ranks}), "
               f"a job of {duration(ask)}" + (" (capped by --max-time; the job resubmits itself)"
                                              if ask < _job_seconds(wall) else ""))
    click.echo(_overhead_text(basis, ranks))
    click.echo(_load_text())
    size = file_bytes(study)
    free = atomic.free_bytes(path)                 # (through the module: one place a test stands the disk in)
    click.echo(f"output: {path} ({size_text(size)} for the {len(study.cases)} cases it starts with, every sample and "
               f"snapshot preallocated; {size_text(free)} free there"
               + (": not enough, the campaign would refuse to start)" if size > free else ")"))
    if not slurm_file:
        return
    hpcves = _hpcves()
    likely = f"likely {basis.core_seconds / 3600:.3g}, " if estimate.likely else ""
    jobs = max_jobs or default_max_jobs(estimate.wall(ranks), ask)
    memory, largest = memory_per_rank(study)
    text = slurm_script(script=Path(slurm_file), study_name=study.name, study_file=Path(study_file), output=path,
                        size=JobSize(ranks, ask, memory, jobs), hpcves=Path(hpcves),
                        python=Path(sys.executable), workdir=Path.cwd(), stop_timeout=study.stop_timeout,
                        summary=f"{estimate.cases} cases at most; core-hours {likely}at most "
                                f"{estimate.core_seconds / 3600:.3g}; {duration(wall)} on {ranks} ranks",
                        largest_N=largest, template=template)
    try:
        Path(slurm_file).write_text(text)
        Path(slurm_file).chmod(0o755)
    except OSError as exc:
        fail(f"cannot write the batch script: {os_error_text(exc)}")
    click.echo(f"batch script: {slurm_file}, from {slurm_template or 'the default template'}: {ranks} ranks, "
               f"{duration(ask)} a job, at most {jobs} jobs, {mem_per_cpu(memory)} MiB a rank "
               f"(set --account and --partition in it, then sbatch {slurm_file})")


def _hpcves() -> Path:
    """The hpcves command the batch script runs."""
    return Path(shutil.which("hpcves") or Path(sys.executable).with_name("hpcves"))


#: the cases a rank should get at least, where that costs little wall time: each rank pays its start-up,
#: and rank 0 serves every other one
CASES_PER_RANK = 3


def _short(seconds: float) -> str:
    """~0.52 ms, ~40 ms, ~2.5 s: a duration that may be well under a second."""
    return f"~{1e3 * seconds:.2g} ms" if seconds < 1 else f"~{duration(seconds)}"


def _overhead_text(basis, ranks: int) -> str:
    """What rank 0 does alone (in the wall times), what analyze takes afterwards, and the cases per rank
    at the suggestion -- with why, where they are fewer than CASES_PER_RANK."""
    def about(seconds):
        return "under 1 s" if seconds < 1 else f"~{duration(seconds)}"

    staged = basis.mode != "grid" and basis.analysis > 0
    text = (f"rank 0 alone: laying out the {basis.cases} cases {about(basis.creation)} (in the wall times above"
            + (f"; each rank classifies the cases it ran as they end, {_short(basis.analysis / basis.cases)} "
               "a case, in the cases' times" if staged else "")
            + f"); hpcves analyze afterwards {about(basis.analysis)} (the "
            "classification; reading the file, figures and case pages come on top)")
    per = basis.cases / computing_ranks(ranks)
    shown = f"{per:,.0f}" if per >= 100 else f"{per:.3g}"
    schedules = " (rank 0 only schedules)" if computing_ranks(ranks) < ranks else ""
    if per >= CASES_PER_RANK or ranks == 1:
        return text + f"\n{shown} cases a rank at the suggestion{schedules}"
    fewer = ranks_for(max(1, basis.cases // CASES_PER_RANK))
    return (text + f"\n{shown} cases a rank at the suggestion{schedules}, fewer than {CASES_PER_RANK}: "
            "the cases are few "
            f"for their length -- {fewer} rank{'s' * (fewer != 1)} ({CASES_PER_RANK} cases each) would take "
            f"{duration(basis.wall(fewer))} instead of {duration(basis.wall(ranks))}")


def _load_text() -> str:
    """What the wall times assume about the machine: a core per rank, as fast as when the step was timed."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"the wall times assume a core for every rank, each as fast as when the step was timed here (load "
            f"average {load:.1f} on {cores} core{'s' * (cores != 1)} then); where the ranks share cores with other "
            "jobs they stretch with the load (a campaign on a shared 2-core machine took 2.9x its plan)")


def _job_seconds(wall: float) -> float:
    """What to ask of the batch system for an estimate ``wall``: 1.5 x it plus 10 minutes (start-up,
    a shared node, the estimate's spread: docs/numerics.md), in whole quarter hours."""
    return 900.0 * math.ceil((1.5 * wall + 600.0) / 900.0)


def _plan_text(estimate, study, suggested: int) -> str:
    """The plan as tables: each stage's cases and core-hours, then the wall time against ranks."""
    likely = estimate.likely
    critical = "critical-shear" if study.search is None or study.search.along == "shear_rate" else "critical-lambda"
    kind = {"grid": "a grid", "search": f"{estimate.units} {critical} search{'es' * (estimate.units != 1)}",
            "refine": f"{estimate.units} refinement{'s' * (estimate.units != 1)}"}[estimate.mode]
    per_step = ", ".join(f"N = {n}: {1e3 * a:.2g}" + (f" to {1e3 * b:.2g}" if f"{a:.2g}" != f"{b:.2g}" else "")
                         + " ms" for n, (a, b) in sorted(estimate.step_seconds.items()))
    lines = [f"{study.name}: {kind}; a step takes {per_step} here (samples and snapshots included)"]
    header = ["stage", "cases", "core-hours"] + (["core-hours if run to t_end"] if likely else [])
    rows = []
    for i, stage in enumerate(estimate.stages):
        rounds = f" (x {stage.rounds})" if stage.rounds > 1 else ""
        note = "" if i == 0 else " at most"
        rows.append([stage.name + rounds, f"{stage.cases}{note}"]
                    + ([f"{likely.stages[i].core_seconds / 3600:.3g}"] if likely else [])
                    + [f"{stage.core_seconds / 3600:.3g}"])
    staged = len(estimate.stages) > 1
    rows.append(["in all", f"{estimate.cases}{' at most' * staged}"]
                + ([f"{likely.core_seconds / 3600:.3g}"] if likely else []) + [f"{estimate.core_seconds / 3600:.3g}"])
    lines.append(markdown_table(header, rows))
    if likely:
        lines.append(f"until_decided: core-hours are what cases typically take to be decided ({DECIDED_AFTER:g} x "
                     "decided_shear_times shear times; 0.8 to 1.7 x for 80 % of the cases measured); the last "
                     "column if none stops early")
    if estimate.mode == "refine":
        lines.append("a refinement's later stages spend at most its budget (max_cases); how much depends on "
                     "the boundaries it finds")
    basis = likely or estimate
    most = ranks_for(basis.widest)
    ranks = sorted({1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024, suggested, most} & set(range(1, most + 1)))
    body = [[f"{p}" + (" (suggested)" if p == suggested else ""), duration(basis.wall(p)),
             f"{100 * basis.core_seconds / (p * basis.wall(p)):.0f} %"]
            + ([duration(estimate.wall(p))] if likely else []) for p in ranks]
    lines.append(markdown_table(["ranks", "wall time", "ranks busy"] + (["if run to t_end"] if likely else []),
                                body))
    return "\n".join(lines)
