"""``hpcves run``: one case, from its TOML into a new HDF5 file, or continued from its last checkpoint."""
from __future__ import annotations

import sys

import click

from hpcves.cli.refuse import refuse_a_campaign_file, refuse_a_study_as_case
from hpcves.cli.terminal import OneLinePath, ProgressLine, StopFlag, clean_errors, compiling, duration
from hpcves.config import load_case
from hpcves.run.casefile import create_case_file, open_for_resume, run_file
from hpcves.run.store import FAILED, FINISHED, MODEL_LIMIT, STATUS_NAMES, CaseStore

RUN_EXIT = ("Exit status: 0 finished, or stopped cleanly with a checkpoint (SIGINT/SIGTERM); 1 the computation "
            "diverged or is under-resolved (the file keeps its last good checkpoint and says why); 2 bad input, or a "
            "file system that refused a write.")


@click.command("run", epilog=RUN_EXIT)
@click.argument("case_file", required=False, type=OneLinePath())
@click.option("--out", "out", type=OneLinePath(), help="HDF5 file to write (new).")
@click.option("--resume", "resume", type=OneLinePath(),
              help="Continue the run in this HDF5 file from its last checkpoint.")
@click.option("--overwrite", is_flag=True, help="Replace an existing --out file.")
@click.option("--quiet", is_flag=True, help="No progress line.")
@clean_errors
def run_command(case_file, out, resume, overwrite, quiet):
    """Run one case: hpcves run CASE.toml --out case.h5, or continue one: hpcves run --resume case.h5."""
    if resume and (case_file or out):
        raise click.UsageError("--resume FILE takes the case from the file; give no CASE_FILE or --out")
    if not resume and not (case_file and out):
        raise click.UsageError("give CASE_FILE and --out FILE, or --resume FILE")

    if resume:
        path = resume
        refuse_a_campaign_file(path)
        opened = open_for_resume(path)
        store = CaseStore(opened.h5)
        if store.status in (FINISHED, MODEL_LIMIT):
            t_done, ended = store.progress[0], STATUS_NAMES[store.status]
            opened.close()
            click.echo(f"{path}: {ended} already (t = {t_done:.6g}); nothing to do.")
            return
    else:
        path = out
        refuse_a_study_as_case(case_file)
        opened = create_case_file(path, load_case(case_file), overwrite)
        store = CaseStore(opened.h5)
    case = store.case
    click.echo(f"{path}: {case.numerics.grid()}, {case.numerics.step_text()}, t_end = {case.run.t_end:g}, "
               f"S = {case.physics.shear_rate:g}, psi_bar = {case.physics.psi_bar:g}, "
               f"excess length = {case.physics.excess_length:g}"
               + (f", viscosity ratio = {case.physics.viscosity_ratio:g}" if case.physics.contrast else "")
               + (f", {case.physics.initial_shape} start" if case.physics.initial_shape != "ellipse" else "")
               + (f", {case.physics.initial_phase} phase" if case.physics.initial_phase != "published" else "")
               + ("  (resuming)" if resume else ""),
               err=True)
    if not quiet and compiling():
        click.echo("compiling the time step (numba: the first run on this machine, ~20-50 s; cached for every "
                   "later run)", err=True)
    progress = None if quiet else ProgressLine()
    try:
        with StopFlag() as stop:
            outcome = run_file(opened, resume=bool(resume), progress=progress, stop_requested=stop)
    finally:
        if progress is not None:
            progress.close()
    rate = outcome.steps / outcome.wall if outcome.wall > 0 else 0.0
    summary = (f"{path}: {STATUS_NAMES[outcome.status]} at t = {outcome.t:.6g} "
               f"({outcome.steps} steps in {duration(outcome.wall)}, {rate:,.0f} steps/s)")
    if outcome.status == FAILED:
        click.echo(summary + f"\n{outcome.message}", err=True)
        sys.exit(1)
    if outcome.status == MODEL_LIMIT:               # an outcome of the model, not a fault: exit 0
        summary += f"\n{outcome.message}"
    elif outcome.status != FINISHED:
        summary += f"; resume with: hpcves run --resume {path}"
    elif outcome.message:                       # a finished run says why only when it stopped early (decided)
        summary += f"\n{outcome.message}"
    click.echo(summary)
