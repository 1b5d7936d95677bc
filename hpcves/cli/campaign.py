"""``hpcves campaign``: a study run on the ranks of MPI_COMM_WORLD, its progress on rank 0's terminal, its
summary at the end; ``--plan`` hands over to cli/plan.py."""
from __future__ import annotations

import sys
import traceback
from pathlib import Path

import click

from hpcves.campaign import IO_MODES
from hpcves.campaign.driver import run_campaign
from hpcves.campaign.study import load_study
from hpcves.cli.plan import print_plan
from hpcves.cli.terminal import CampaignProgress, OneLinePath, StopFlag, compiling, duration, error, fail, os_error_text
from hpcves.errors import HpcvesError
from hpcves.files.atomic import check_output_path
from hpcves.reports.critical import critical_table, write_critical_csv
from hpcves.reports.refinement import refinement_columns
from hpcves.reports.tables import markdown_table, write_rows

CAMPAIGN_EXIT = ("Exit status: 0 every case finished or at the model's limit (or stopped cleanly); 1 a case failed; "
                 "2 bad input, or a file system that refused a write (full disk, read-only, ...).")


def mpi_world():
    """COMM_WORLD, or None where mpi4py is not installed (then the campaign runs in this process)."""
    try:
        from mpi4py import MPI
    except ImportError:
        return None
    return MPI.COMM_WORLD


@click.command("campaign", epilog=CAMPAIGN_EXIT)
@click.argument("study_file", type=OneLinePath())
@click.option("--resume", is_flag=True,
              help="Continue the campaign file (finished cases are kept, running ones continue from "
                   "their checkpoints); starts it if it does not exist yet.")
@click.option("--retry-failed", is_flag=True, help="With --resume: run the failed cases again, from the start.")
@click.option("--overwrite", is_flag=True, help="Delete an existing campaign file and start over.")
@click.option("--out", "out", type=OneLinePath(), help="Campaign file (default: [campaign] output).")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.option("--io", "io", type=click.Choice(IO_MODES), default="auto", show_default=True,
              help="How several ranks write the file: mpio (parallel HDF5, every rank writes its cases), "
                   "relay (rank 0 writes for everyone: for an h5py without MPI, or a file system where "
                   "MPI-IO misbehaves), auto (mpio if h5py has MPI).")
@click.option("--plan", "show_plan", is_flag=True,
              help="Run nothing: time a step at each N here, then print the cases, the core-hours, and "
                   "the wall time on a suggested number of ranks (without mpirun).")
@click.option("--slurm", "slurm_file", type=OneLinePath(),
              help="With --plan: also write a SLURM batch script sized from the plan to this file.")
@click.option("--max-time", type=float, default=24.0, show_default=True,
              help="With --plan: the longest job to ask for, in hours (the script resubmits itself "
                   "while work is left).")
@click.option("--slurm-template", "slurm_template", type=OneLinePath(),
              help="With --slurm: your site's batch-script template instead of the default "
                   "(hpcves/campaign/templates/slurm.sh; its {{ placeholders }}: docs/cluster.md).")
@click.option("--max-jobs", type=int,
              help="With --slurm: the most jobs the script's chain may run, resubmissions included "
                   "(default: twice the jobs the plan needs, plus one).")


def campaign_command(study_file, resume, retry_failed, overwrite, out, quiet, io, show_plan, slurm_file, max_time,
                     slurm_template, max_jobs):
    """Run a study: mpirun -n P hpcves campaign STUDY.toml (or without mpirun, on one core).

    With --plan nothing runs: the cases, core-hours, ranks and wall time it will take (and with
    --slurm a batch script sized from them).

    Exit status: 0 every case finished or at the model's limit (or the campaign was stopped by a signal
    and can be resumed), 1 some case failed, 2 bad input.
    """
    comm = mpi_world()
    size = 1 if comm is None else comm.Get_size()
    rank = 0 if comm is None else comm.Get_rank()
    if slurm_file and not show_plan:
        fail("--slurm goes with --plan (hpcves campaign STUDY.toml --plan --slurm job.sh)")
    for given, name in ((slurm_template, "--slurm-template"), (max_jobs is not None, "--max-jobs")):
        if given and not slurm_file:
            fail(f"{name} goes with --plan --slurm (hpcves campaign STUDY.toml --plan --slurm job.sh {name} ...)")
    if show_plan:
        if size > 1:
            if rank == 0:
                click.echo("Error: --plan runs nothing in parallel: leave out mpirun", err=True)
            sys.exit(2)
        print_plan(study_file, out and Path(out), slurm_file and Path(slurm_file), max_time,
                   slurm_template and Path(slurm_template), max_jobs)
        return
    try:
        _campaign(comm, size, rank, study_file, resume, retry_failed, overwrite, out and Path(out), quiet, io)
    except SystemExit:
        raise
    except OSError as exc:                             # the file system refused (on this rank): one line
        click.echo(f"Error: {os_error_text(exc)}", err=True)
        if size > 1:
            comm.Abort(2)
        sys.exit(2)
    except BaseException:                              # a bug, or a second Ctrl-C: never leave ranks hanging

        traceback.print_exc()
        if size > 1:
            comm.Abort(1)
        sys.exit(1)


def _on_rank_0(comm, size, rank, work):
    """``work()`` on rank 0, its value on every rank; an HpcvesError there ends every rank with its
    message (on rank 0) and exit status 2."""
    result = None
    if rank == 0:
        try:
            result = ("ok", work())
        except HpcvesError as exc:
            result = ("error", str(exc))
    if size > 1:
        result = comm.bcast(result, root=0)
    if result[0] == "error":
        if rank == 0:
            error(result[1])
        sys.exit(2)
    return result[1]


class _CampaignTerminal:
    """What a campaign shows on rank 0's terminal: its lines, a progress display per stage (unless
    quiet), and after each stage of a search or refinement its CSV and a line of where it stands."""
    def __init__(self, study, path, quiet: bool):
        self.study, self.quiet, self.display = study, quiet, None
        stem = study.search.stem if study.search else "critical_shear"
        self.critical_csv = path.with_name(f"{path.stem}_{stem}.csv")
        self.refine_csv = path.with_name(path.stem + "_refinement.csv")

    def announce(self, text, n_cases, ended_before):
        self.close()
        click.echo(text, err=True)
        if n_cases is not None and not self.quiet:
            self.display = CampaignProgress(n_cases, ended_before)

    def show(self, stage):
        if self.display is not None:
            self.display(stage)

    def close(self):
        if self.display is not None:
            self.display.close()
            self.display = None

    def on_stage(self, outcomes):
        if self.study.refine:

            write_rows([o.row() for o in outcomes], refinement_columns(self.study), self.refine_csv)
            kind, csv_path, brief = "refinements", self.refine_csv, lambda o: o.brief()
        else:

            write_critical_csv([o.row() for o in outcomes], self.critical_csv, self.study.search.along)
            kind, csv_path, brief = "searches", self.critical_csv, _search_brief
        if not any(o.regimes for o in outcomes):          # a new search or refinement: nothing found yet
            return
        ended = sum(1 for o in outcomes if o.state.status != "running")
        detail = "; ".join(brief(o) for o in outcomes) if len(outcomes) <= 8 else f"see {csv_path}"
        self.announce(f"{kind}: {ended} of {len(outcomes)} ended; {detail}", None, (0, 0))


def _campaign(comm, size, rank, study_file, resume, retry_failed, overwrite, out, quiet, io):

    if retry_failed and not resume:
        if rank == 0:
            click.echo("Error: --retry-failed goes with --resume", err=True)
        sys.exit(2)
    study = _on_rank_0(comm, size, rank, lambda: load_study(study_file))
    path = out or study.output
    _on_rank_0(comm, size, rank, lambda: check_output_path(path))
    terminal = _CampaignTerminal(study, path, quiet)
    if rank == 0 and not quiet and compiling():
        click.echo("compiling the time step (numba: the first campaign on this machine, ~20-50 s on every rank; "
                   "cached for every later run)", err=True)
    try:
        with StopFlag() as stop:
            summary = run_campaign(study, path, comm if size > 1 else None, resume=resume,
                                   retry_failed=retry_failed, overwrite=overwrite, io=io, stop_flag=stop,
                                   display=terminal.show, announce=terminal.announce, on_stage=terminal.on_stage)
    except HpcvesError as exc:
        if rank == 0:
            error(exc)
        sys.exit(2)
    finally:
        terminal.close()
    if rank == 0:
        _print_summary(summary, path)
        if summary.searches and study.refine:
            _print_refinements(study, summary.searches, terminal.refine_csv)
        elif summary.searches:
            _print_searches(summary.searches, terminal.critical_csv)
        if summary.not_written:
            click.echo(f"Error: {summary.not_written}; the campaign stopped and every case keeps its last "
                       "valid checkpoint: free some space, then continue with --resume", err=True)
    sys.exit(summary.exit_status)


def _search_brief(outcome) -> str:
    """``psi_bar = 0.3: [40, 56.6]``: one search in a few characters."""
    point = ", ".join(f"{k} = {v:g}" for k, v in outcome.point.items() if k in outcome.swept_keys) or outcome.column
    state = outcome.state
    if state.status == "converged":
        return f"{point}: {outcome.column} in [{state.low:.4g}, {state.high:.4g}]"
    if state.status == "running" and state.low == state.low:
        return f"{point}: [{state.low:g}, {state.high:g}]"
    return f"{point}: {state.status}"


def _print_searches(outcomes, critical_csv) -> None:

    click.echo(critical_table([o.row() for o in outcomes], outcomes[0].swept_keys, outcomes[0].column))
    click.echo(f"critical {'shear rates' if outcomes[0].symbol == 'S' else 'viscosity ratios'}: {critical_csv} (the "
               "brackets; hpcves analyze adds the best estimate inside each)")


def _print_refinements(study, outcomes, refine_csv) -> None:

    columns = refinement_columns(study)
    click.echo(markdown_table(list(columns), [[f"{v:g}" if isinstance(v, float) else str(v)
                                               for v in (o.row()[c] for c in columns)] for o in outcomes],
                              left=(len(columns) - 6, len(columns) - 1)))
    click.echo(f"refinements: {refine_csv}; hpcves analyze draws the boundaries")


def _print_summary(summary, path) -> None:
    counts = ", ".join(f"{n} {name}" for name, n in summary.counts.items() if n)
    ran = len(summary.ran)
    click.echo(f"{path}: {counts} ({ran} case{'s' * (ran != 1)} run in this call, {duration(summary.wall)})")
    for case_id, message in summary.failed:
        click.echo(f"  case {case_id} failed: {message.splitlines()[0] if message else '?'}", err=True)
    if summary.run_again:
        click.echo(f"  {summary.run_again} case{'s' * (summary.run_again != 1)} ran again (under-resolved: at a "
                   "larger N, refine.max_N; creeping: with a tighter resize_tail, refine.min_resize_tail); the "
                   "later run is the point's", err=True)
    if summary.counts.get("interrupted", 0) or summary.counts.get("running", 0) or summary.counts.get("pending", 0):
        click.echo("  not finished: continue with --resume", err=True)
    if summary.failed:
        click.echo("  hpcves status shows the failures; --resume --retry-failed reruns them", err=True)
