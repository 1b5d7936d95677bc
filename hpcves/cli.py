"""The ``hpcves`` command line.

Exit status: 0 done (or stopped cleanly with a checkpoint written, or at the model's limit:
psi left [0, 1] under the linear bending law), 1 the computation failed (diverged), 2 bad
input (configuration, files).
"""
from __future__ import annotations

import functools
import json
import logging
import math
import os
import signal
import sys
import time
from collections import Counter

import click

from hpcves.analysis import accuracy
from hpcves.campaign import IO_MODES
from hpcves.errors import HpcvesError
from hpcves.files.atomic import check_output_path
from hpcves.model.params import ConfigError
from hpcves.version import __version__


def _error(message) -> None:
    """``Error: <problem>`` on stderr, a line for each problem (a file's problems come together:
    config.Problems)."""
    for line in str(message).splitlines() or [""]:
        click.echo(f"Error: {line}", err=True)


def _fail(message: str) -> None:
    """_error, and exit status 2."""
    _error(message)
    sys.exit(2)


def os_error_text(exc: OSError) -> str:
    """``path: reason`` of an error of the file system, in one line."""
    reason = exc.strerror or (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    return f"{exc.filename}: {reason}" if exc.filename else reason


def clean_errors(func):
    """Bad input of any kind, or a file system that refuses: one line on stderr, exit status 2."""
    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except HpcvesError as exc:          # ConfigError, FileFormatError, LockError, StorageError
            _fail(str(exc))
        except OSError as exc:              # a full disk, permissions, a directory where a file belongs
            _fail(os_error_text(exc))
    return wrapper


class _StatusLine:
    """One status line on stderr: rewritten in place on a terminal; on a pipe or a log
    file, written as a new line at most every LOG_SECONDS."""

    LOG_SECONDS = 30.0

    def __init__(self, stream=sys.stderr):
        self.stream = stream
        self.tty = stream.isatty()
        self._last = 0.0
        self._width = 0

    def due(self, tty_interval: float = 0.0) -> bool:
        """Whether a new line would be shown now (terminals: every ``tty_interval`` seconds)."""
        return time.monotonic() - self._last >= (tty_interval if self.tty else self.LOG_SECONDS)

    def show(self, text: str) -> None:
        self._last = time.monotonic()
        if self.tty:
            self.stream.write("\r" + text.ljust(self._width))
            self._width = len(text)
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.tty and self._width:
            self.stream.write("\n")
            self.stream.flush()


class ProgressLine(_StatusLine):
    """``t = 0.512 / 5  |  1043 steps/s  |  ETA 4 s  |  theta = 0.581`` on stderr."""

    def __init__(self, label: str = "", stream=sys.stderr):
        super().__init__(stream)
        self.label = label

    def __call__(self, tick) -> None:
        if self.due():
            self.show(f"{self.label}t = {tick.t:.4g} / {tick.t_end:.4g}  |  {tick.steps_per_second:,.0f} steps/s"
                      f"  |  ETA {_duration(tick.eta_seconds)}  |  theta = {tick.theta:.4f}")


def _duration(seconds: float) -> str:
    if seconds != seconds or seconds == float("inf"):
        return "?"
    seconds = int(round(seconds))
    if seconds < 120:
        return f"{seconds} s"
    if seconds < 7200:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {(seconds % 3600) // 60:02d} min"


class _SigtermSeen:
    """A SIGTERM handler that only notes the signal; the work polls it and ends at a point of its own
    choosing. (Raising SystemExit in the handler, where the signal landed, was lost when that was a
    finalizer -- a weakref callback during garbage collection: Python printed it and went on, and
    `--plan` finished with status 0.)"""

    def __init__(self):
        self.signum = None

    def __call__(self, signum, frame):
        self.signum = signum

    def seen(self) -> bool:
        return self.signum is not None


class StopFlag:
    """SIGINT / SIGTERM set a flag that the run loop polls (it then checkpoints and stops)."""

    def __init__(self):
        self.raised = None
        self._old = {}

    def __enter__(self):
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._old[sig] = signal.signal(sig, self._handler)
        return self

    def _handler(self, signum, frame):
        if self.raised is not None:          # second signal: give up at once
            raise KeyboardInterrupt
        self.raised = signal.Signals(signum).name

    def __call__(self) -> bool:
        return self.raised is not None

    def __exit__(self, *exc):
        for sig, handler in self._old.items():
            signal.signal(sig, handler)
        return False


class _TerminalLog(logging.Handler):
    """The library's log records (``logging.getLogger("hpcves")``) on stderr: INFO and up, one line
    each, ``[rank R]`` in front when the job has several ranks, on a line of its own after a status
    line being rewritten on a terminal."""

    def __init__(self, stream=None):
        super().__init__(logging.INFO)
        self.stream = stream or sys.stderr

    @staticmethod
    def _rank() -> str:
        mpi = sys.modules.get("mpi4py.MPI")          # only if a command started MPI: never start it here
        if mpi is None or not mpi.Is_initialized() or mpi.Is_finalized() or mpi.COMM_WORLD.Get_size() == 1:
            return ""
        return f"[rank {mpi.COMM_WORLD.Get_rank()}] "

    def emit(self, record):
        try:
            lead = "\n" if self.stream.isatty() else ""
            self.stream.write(f"{lead}{self._rank()}{record.getMessage()}\n")
            self.stream.flush()
        except Exception:                            # noqa: BLE001  (logging's rule: never raise)
            self.handleError(record)


def _log_to_terminal() -> None:
    library = logging.getLogger("hpcves")
    if not any(isinstance(h, _TerminalLog) for h in library.handlers):
        library.addHandler(_TerminalLog())
        library.setLevel(logging.INFO)
        library.propagate = False


@click.group()
@click.version_option(__version__, prog_name="hpcves")
def main():
    """Two-phase vesicles in shear flow: simulations, campaigns, analysis."""
    _log_to_terminal()


RUN_EXIT = ("Exit status: 0 finished, or stopped cleanly with a checkpoint (SIGINT/SIGTERM); 1 the computation "
            "diverged or is under-resolved (the file keeps its last good checkpoint and says why); 2 bad input, or a "
            "file system that refused a write.")
CAMPAIGN_EXIT = ("Exit status: 0 every case finished or at the model's limit (or stopped cleanly); 1 a case failed; "
                 "2 bad input, or a file system that refused a write (full disk, read-only, ...).")


@main.command("run", epilog=RUN_EXIT)
@click.argument("case_file", required=False, type=click.Path())
@click.option("--out", "out", type=click.Path(), help="HDF5 file to write (new).")
@click.option("--resume", "resume", type=click.Path(),
              help="Continue the run in this HDF5 file from its last checkpoint.")
@click.option("--overwrite", is_flag=True, help="Replace an existing --out file.")
@click.option("--quiet", is_flag=True, help="No progress line.")
@clean_errors
def run_command(case_file, out, resume, overwrite, quiet):
    """Run one case: hpcves run CASE.toml --out case.h5, or continue one: hpcves run --resume case.h5."""
    from hpcves.config import load_case
    from hpcves.run.casefile import create_case_file, open_for_resume, run_file
    from hpcves.run.store import FAILED, FINISHED, MODEL_LIMIT, STATUS_NAMES, CaseStore

    if resume and (case_file or out):
        raise click.UsageError("--resume FILE takes the case from the file; give no CASE_FILE or --out")
    if not resume and not (case_file and out):
        raise click.UsageError("give CASE_FILE and --out FILE, or --resume FILE")

    if resume:
        path = resume
        _refuse_a_campaign_file(path)
        h5 = open_for_resume(path)
        store = CaseStore(h5)
        if store.status in (FINISHED, MODEL_LIMIT):
            t_done, ended = store.progress[0], STATUS_NAMES[store.status]
            h5.close()
            click.echo(f"{path}: {ended} already (t = {t_done:.6g}); nothing to do.")
            return
    else:
        path = out
        _refuse_a_study_as_case(case_file)
        h5 = create_case_file(path, load_case(case_file), overwrite)
        store = CaseStore(h5)
    case = store.case
    step = f"rtol = {case.numerics.rtol:g}" if case.numerics.adaptive else f"dt = {case.numerics.dt:g}"
    click.echo(f"{path}: {case.numerics.grid()}, {step}, t_end = {case.run.t_end:g}, "
               f"S = {case.physics.shear_rate:g}, psi_bar = {case.physics.psi_bar:g}, "
               f"excess length = {case.physics.excess_length:g}"
               + (f", viscosity ratio = {case.physics.viscosity_ratio:g}" if case.physics.contrast else "")
               + (f", {case.physics.initial_shape} start" if case.physics.initial_shape != "ellipse" else "")
               + (f", {case.physics.initial_phase} phase" if case.physics.initial_phase != "published" else "")
               + ("  (resuming)" if resume else ""),
               err=True)
    progress = None if quiet else ProgressLine()
    try:
        with StopFlag() as stop:
            outcome = run_file(h5, resume=bool(resume), progress=progress, stop_requested=stop)
    finally:
        if progress is not None:
            progress.close()
    rate = outcome.steps / outcome.wall if outcome.wall > 0 else 0.0
    summary = (f"{path}: {STATUS_NAMES[outcome.status]} at t = {outcome.t:.6g} "
               f"({outcome.steps} steps in {_duration(outcome.wall)}, {rate:,.0f} steps/s)")
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


class CampaignProgress(_StatusLine):
    """``[######......] 12/40 cases | 2 running | 1 failed | 31 % | ETA 14 min`` on rank 0's stderr.

    Cases that ended before this call (``ended_before``: how many, and how many of them failed) count as
    done and failed. The fraction is of the total cost (steps x N^2), counting running cases by how far
    they have got; the ETA extrapolates this call's rate.
    """

    def __init__(self, n_total: int, ended_before: tuple[int, int] = (0, 0), stream=sys.stderr):
        super().__init__(stream)
        self.n_total = n_total
        self.n_done_before, self.n_failed_before = ended_before
        self.start = time.monotonic()

    def __call__(self, stage) -> None:
        """Show ``stage``, a driver.StageProgress."""
        if not self.due(0.5):
            return
        elapsed = time.monotonic() - self.start
        fraction = stage.fraction
        eta = elapsed * (1.0 - fraction) / fraction if fraction > 0.0 else float("inf")
        bar = "#" * int(round(20 * fraction))
        self.show(f"[{bar:<20}] {self.n_done_before + stage.ended}/{self.n_total} cases | "
                  f"{stage.running} running | {self.n_failed_before + stage.failed} failed | {100 * fraction:.0f} % | "
                  f"ETA {_duration(eta)}")


def _mpi_world():
    """COMM_WORLD, or None where mpi4py is not installed (then the campaign runs in this process)."""
    try:
        from mpi4py import MPI
    except ImportError:
        return None
    return MPI.COMM_WORLD


@main.command("campaign", epilog=CAMPAIGN_EXIT)
@click.argument("study_file", type=click.Path())
@click.option("--resume", is_flag=True,
              help="Continue the campaign file (finished cases are kept, running ones continue from "
                   "their checkpoints); starts it if it does not exist yet.")
@click.option("--retry-failed", is_flag=True, help="With --resume: run the failed cases again, from the start.")
@click.option("--overwrite", is_flag=True, help="Delete an existing campaign file and start over.")
@click.option("--out", "out", type=click.Path(), help="Campaign file (default: [campaign] output).")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.option("--io", "io", type=click.Choice(IO_MODES), default="auto", show_default=True,
              help="How several ranks write the file: mpio (parallel HDF5, every rank writes its cases), "
                   "relay (rank 0 writes for everyone: for an h5py without MPI, or a file system where "
                   "MPI-IO misbehaves), auto (mpio if h5py has MPI).")
@click.option("--plan", "show_plan", is_flag=True,
              help="Run nothing: time a step at each N here, then print the cases, the core-hours, and "
                   "the wall time on a suggested number of ranks (without mpirun).")
@click.option("--slurm", "slurm_file", type=click.Path(),
              help="With --plan: also write a SLURM batch script sized from the plan to this file.")
@click.option("--max-time", type=float, default=24.0, show_default=True,
              help="With --plan: the longest job to ask for, in hours (the script resubmits itself "
                   "while work is left).")
@click.option("--slurm-template", "slurm_template", type=click.Path(),
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
    from pathlib import Path

    comm = _mpi_world()
    size = 1 if comm is None else comm.Get_size()
    rank = 0 if comm is None else comm.Get_rank()
    if slurm_file and not show_plan:
        _fail("--slurm goes with --plan (hpcves campaign STUDY.toml --plan --slurm job.sh)")
    for given, name in ((slurm_template, "--slurm-template"), (max_jobs is not None, "--max-jobs")):
        if given and not slurm_file:
            _fail(f"{name} goes with --plan --slurm (hpcves campaign STUDY.toml --plan --slurm job.sh {name} ...)")
    if show_plan:
        if size > 1:
            if rank == 0:
                click.echo("Error: --plan runs nothing in parallel: leave out mpirun", err=True)
            sys.exit(2)
        _plan(study_file, out and Path(out), slurm_file and Path(slurm_file), max_time,
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
        import traceback

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
            _error(result[1])
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
            from hpcves.reports.refinement import refinement_columns
            from hpcves.reports.tables import write_rows

            write_rows([o.row() for o in outcomes], refinement_columns(self.study), self.refine_csv)
            kind, csv_path, brief = "refinements", self.refine_csv, lambda o: o.brief()
        else:
            from hpcves.reports.critical import write_critical_csv

            write_critical_csv([o.row() for o in outcomes], self.critical_csv, self.study.search.along)
            kind, csv_path, brief = "searches", self.critical_csv, _search_brief
        if not any(o.regimes for o in outcomes):          # a new search or refinement: nothing found yet
            return
        ended = sum(1 for o in outcomes if o.state.status != "running")
        detail = "; ".join(brief(o) for o in outcomes) if len(outcomes) <= 8 else f"see {csv_path}"
        self.announce(f"{kind}: {ended} of {len(outcomes)} ended; {detail}", None, (0, 0))


def _campaign(comm, size, rank, study_file, resume, retry_failed, overwrite, out, quiet, io):
    from hpcves.campaign.driver import run_campaign
    from hpcves.campaign.study import load_study

    if retry_failed and not resume:
        if rank == 0:
            click.echo("Error: --retry-failed goes with --resume", err=True)
        sys.exit(2)
    study = _on_rank_0(comm, size, rank, lambda: load_study(study_file))
    path = out or study.output
    _on_rank_0(comm, size, rank, lambda: check_output_path(path))
    terminal = _CampaignTerminal(study, path, quiet)
    try:
        with StopFlag() as stop:
            summary = run_campaign(study, path, comm if size > 1 else None, resume=resume,
                                   retry_failed=retry_failed, overwrite=overwrite, io=io, stop_flag=stop,
                                   display=terminal.show, announce=terminal.announce, on_stage=terminal.on_stage)
    except HpcvesError as exc:
        if rank == 0:
            _error(exc)
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


@clean_errors
def _plan(study_file, out, slurm_file, max_time, slurm_template=None, max_jobs=None) -> None:
    """``hpcves campaign --plan``: what the study will cost, and a batch script sized from it."""
    import shutil
    from pathlib import Path

    from hpcves.campaign.driver import file_bytes
    from hpcves.campaign.plan import memory_per_rank, plan
    from hpcves.campaign.slurm import JobSize, mem_per_cpu, read_template, slurm_script
    from hpcves.campaign.slurm import max_jobs as default_max_jobs
    from hpcves.campaign.study import load_study
    from hpcves.files.atomic import free_bytes, size_text
    from hpcves.run.timing import StepCost, classify_seconds, layout_seconds

    try:
        study = load_study(study_file)
    except HpcvesError as exc:
        _fail(str(exc))
    if not max_time > 0:
        _fail(f"--max-time {max_time:g}: must be > 0 hours")
    if slurm_file:
        check_output_path(slurm_file)
        if not Path(slurm_file).absolute().parent.is_dir():        # say so before the timing, not after
            _fail(f"{slurm_file}: its directory {Path(slurm_file).absolute().parent} does not exist")
        try:
            template = read_template(slurm_template)         # refused now, not after the timing
        except HpcvesError as exc:
            _fail(str(exc))
        if max_jobs is not None and max_jobs < 1:
            _fail(f"--max-jobs {max_jobs}: must be at least 1")
    # a step is timed in a scratch directory, removed when the timing ends; SIGTERM (a batch system,
    # `timeout`) would kill the process before that: noted instead, the timing runs stop at their next
    # step, the directory is removed, and the command exits with 128 + 15
    sigterm = _SigtermSeen()
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
               f"a job of {_duration(ask)}" + (" (capped by --max-time; the job resubmits itself)"
                                                if ask < _job_seconds(wall) else ""))
    click.echo(_overhead_text(basis, ranks))
    click.echo(_load_text())
    size = file_bytes(study)
    free = free_bytes(path)
    click.echo(f"output: {path} ({size_text(size)} for the {len(study.cases)} cases it starts with, every sample and "
               f"snapshot preallocated; {size_text(free)} free there"
               + (": not enough, the campaign would refuse to start)" if size > free else ")"))
    if not slurm_file:
        return
    hpcves = shutil.which("hpcves") or str(Path(sys.executable).with_name("hpcves"))
    likely = f"likely {basis.core_seconds / 3600:.3g}, " if estimate.likely else ""
    jobs = max_jobs or default_max_jobs(estimate.wall(ranks), ask)
    memory, largest = memory_per_rank(study)
    text = slurm_script(script=Path(slurm_file), study_name=study.name, study_file=Path(study_file), output=path,
                        size=JobSize(ranks, ask, memory, jobs), hpcves=Path(hpcves),
                        python=Path(sys.executable), workdir=Path.cwd(), stop_timeout=study.stop_timeout,
                        summary=f"{estimate.cases} cases at most; core-hours {likely}at most "
                                f"{estimate.core_seconds / 3600:.3g}; {_duration(wall)} on {ranks} ranks",
                        largest_N=largest, template=template)
    try:
        Path(slurm_file).write_text(text)
        Path(slurm_file).chmod(0o755)
    except OSError as exc:
        _fail(f"cannot write the batch script: {os_error_text(exc)}")
    click.echo(f"batch script: {slurm_file}, from {slurm_template or 'the default template'}: {ranks} ranks, "
               f"{_duration(ask)} a job, at most {jobs} jobs, {mem_per_cpu(memory)} MiB a rank "
               f"(set --account and --partition in it, then sbatch {slurm_file})")


#: the cases a rank should get at least, where that costs little wall time: each rank pays its start-up,
#: and rank 0 serves every other one
CASES_PER_RANK = 3


def _short(seconds: float) -> str:
    """~0.52 ms, ~40 ms, ~2.5 s: a duration that may be well under a second."""
    return f"~{1e3 * seconds:.2g} ms" if seconds < 1 else f"~{_duration(seconds)}"


def _overhead_text(basis, ranks: int) -> str:
    """What rank 0 does alone (in the wall times), what analyze takes afterwards, and the cases per rank
    at the suggestion -- with why, where they are fewer than CASES_PER_RANK."""
    from hpcves.campaign.queue import computing_ranks, ranks_for

    def about(seconds):
        return "under 1 s" if seconds < 1 else f"~{_duration(seconds)}"

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
            f"{_duration(basis.wall(fewer))} instead of {_duration(basis.wall(ranks))}")


def _load_text() -> str:
    """What the wall times assume about the machine: a core per rank, as fast as when the step was timed."""
    import os

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
    from hpcves.campaign.plan import DECIDED_AFTER
    from hpcves.campaign.queue import ranks_for
    from hpcves.reports.tables import markdown_table

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
    body = [[f"{p}" + (" (suggested)" if p == suggested else ""), _duration(basis.wall(p)),
             f"{100 * basis.core_seconds / (p * basis.wall(p)):.0f} %"]
            + ([_duration(estimate.wall(p))] if likely else []) for p in ranks]
    lines.append(markdown_table(["ranks", "wall time", "ranks busy"] + (["if run to t_end"] if likely else []),
                                body))
    return "\n".join(lines)


def _search_brief(outcome) -> str:
    """``psi_bar = 0.3: [40, 56.6]``: one search in a few characters."""
    point = ", ".join(f"{k} = {v:g}" for k, v in outcome.point.items() if k in outcome.swept_keys) or outcome.column
    state = outcome.state
    if state.status == "converged":
        return f"{point}: {outcome.column} = {state.critical:.4g}"
    if state.status == "running" and state.low == state.low:
        return f"{point}: [{state.low:g}, {state.high:g}]"
    return f"{point}: {state.status}"


def _print_searches(outcomes, critical_csv) -> None:
    from hpcves.reports.critical import critical_table

    click.echo(critical_table([o.row() for o in outcomes], outcomes[0].swept_keys, outcomes[0].column))
    click.echo(f"critical {'shear rates' if outcomes[0].symbol == 'S' else 'viscosity ratios'}: {critical_csv}")


def _print_refinements(study, outcomes, refine_csv) -> None:
    from hpcves.reports.refinement import refinement_columns
    from hpcves.reports.tables import markdown_table

    columns = refinement_columns(study)
    click.echo(markdown_table(list(columns), [[f"{v:g}" if isinstance(v, float) else str(v)
                                               for v in (o.row()[c] for c in columns)] for o in outcomes],
                              left=(len(columns) - 6, len(columns) - 1)))
    click.echo(f"refinements: {refine_csv}; hpcves analyze draws the boundaries")


def _print_summary(summary, path) -> None:
    counts = ", ".join(f"{n} {name}" for name, n in summary.counts.items() if n)
    ran = len(summary.ran)
    click.echo(f"{path}: {counts} ({ran} case{'s' * (ran != 1)} run in this call, {_duration(summary.wall)})")
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


@main.command("status")
@click.argument("campaign_file", type=click.Path())
@click.option("--check", is_flag=True,
              help="Also check every dataset of every case (shapes, counters, checkpoints), as --resume does: "
                   "about 3 ms a case instead of 0.2.")
@click.option("--json", "as_json", is_flag=True,
              help="One JSON object on stdout instead of the table: the cases, the totals and what is left.")
@clean_errors
def status_command(campaign_file, check, as_json):
    """One line per case of a campaign file (it may be running), the totals and what is left.

    Exit status: 0 the campaign is complete (nothing left for --resume); 1 complete, but cases
    failed (--resume --retry-failed reruns them); 3 work is left (cases to run, the next stage of
    a search or refinement, a campaign writing the file, or a creation that was cut short:
    resubmit); 2 the file cannot be read or a case is damaged.
    """
    from hpcves.campaign.file import BeingCreated, CreationInterrupted, read_table
    from hpcves.campaign.progress import WORK_LEFT, progress
    from hpcves.run.verdict import DAMAGED

    check_output_path(campaign_file)
    _refuse_a_study_file(campaign_file, "status")
    try:
        table = read_table(campaign_file, check=check)
    except (BeingCreated, CreationInterrupted) as exc:        # work left: a campaign makes it, or --resume will
        if as_json:
            click.echo(json.dumps({"file": str(campaign_file), "complete": False, "left": str(exc),
                                   "exit_status": WORK_LEFT}))
        elif isinstance(exc, CreationInterrupted):
            _error(exc)
        else:
            click.echo(str(exc))
        sys.exit(WORK_LEFT)
    name, rows = table.name, table.rows
    writing = (f"a campaign is writing it ({table.writer})" if table.writer else "no campaign is writing it")
    damaged = [r for r in rows if r["status"] == DAMAGED]
    left = None if damaged else progress(campaign_file, rows, table.writer)
    totals = Counter(r["status"] for r in rows)            # status -> cases, in the order first seen
    if as_json:
        _status_json(campaign_file, table, totals, left)
    elif not rows:
        click.echo(f"{campaign_file}: study {name!r}, no cases; {writing}")
    else:
        _status_table(name, rows, totals, writing, left)
    if damaged:
        _fail(f"{campaign_file}: {len(damaged)} damaged case{'s' * (len(damaged) != 1)} ("
              + "; ".join(f"{r['case']}: {r['message']}" for r in damaged[:3])
              + (f"; {len(damaged) - 3} more" if len(damaged) > 3 else "") + ")")
    sys.exit(left.exit_status)


def _toml_of(path) -> dict | None:
    """The parsed TOML of ``path`` if it is a regular, non-empty text file of TOML (at most 1 MB), else
    None: the reader the command meant to use says what is wrong with it."""
    import stat
    import tomllib

    try:
        info = os.stat(path)
        if not stat.S_ISREG(info.st_mode) or info.st_size == 0 or info.st_size > 1 << 20:
            return None
        with open(path, "rb") as f:
            return tomllib.load(f) or None
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError):
        return None


def _refuse_a_study_as_case(path) -> None:
    """``hpcves run STUDY.toml``: a study (a [campaign] table) is run by ``hpcves campaign``."""
    data = _toml_of(path)
    if data is not None and isinstance(data.get("campaign"), dict):
        _fail(f"{path}: a study file (it has a [campaign] table), not a case: `hpcves campaign {path}` runs it "
              f"(`mpirun -n P hpcves campaign {path}` on P ranks)")


def _refuse_a_campaign_file(path) -> None:
    """``hpcves run --resume CAMPAIGN.h5``: a campaign file is continued by ``hpcves campaign --resume``."""
    from hpcves.campaign.file import FORMAT as CAMPAIGN_FORMAT
    from hpcves.run.store import HDF5_ERRORS, attr_text, open_file

    try:
        with open_file(path, "r", locking=False) as h5:
            kind = attr_text(h5.attrs.get("format", ""))
            source = attr_text(h5.attrs.get("campaign_toml", ""))
    except (OSError, *HDF5_ERRORS):
        return                                        # open_for_resume says what is wrong with it
    if kind == CAMPAIGN_FORMAT:
        _fail(f"{path}: a campaign file, not a case's: `hpcves campaign STUDY.toml --resume` continues it"
              + (" (the study it was made from is stored in the file: campaign_toml)" if source else ""))


def _refuse_a_study_file(path, command: str) -> None:
    """A study file (TOML with a [campaign] table) given where a campaign file is wanted: say which
    command takes it, and where its campaign file is."""
    data = _toml_of(path)
    if data is None:
        return                                        # not a TOML text: the HDF5 reader says what it is
    if isinstance(data.get("campaign"), dict):
        output = data["campaign"].get("output")
        _fail(f"{path}: a study file, not a campaign file: `hpcves {command} "
              + (f"{output}`" if output else "<its output file>`") + f" for its campaign, `hpcves campaign {path}` "
              "to run it")
    _fail(f"{path}: a case file (TOML), not a campaign file: `hpcves run {path} --out FILE.h5` runs it, and "
          f"`hpcves {command}` takes the campaign file of `hpcves campaign`")


def _status_json(campaign_file, table, totals, left) -> None:
    """``hpcves status --json``: the file, the study, every case, the totals and what is left."""
    def plain(value):                       # JSON has no NaN: null
        return None if isinstance(value, float) and not math.isfinite(value) else value
    click.echo(json.dumps({
        "file": str(campaign_file), "study": table.name, "writer": table.writer, "cases": len(table.rows),
        "totals": dict(totals), "complete": None if left is None else left.complete,
        "left": "damaged cases" if left is None else left.left, "failed": totals.get("failed", 0),
        "exit_status": 2 if left is None else left.exit_status,
        "rows": [{k: plain(v) for k, v in r.items()} for r in table.rows]}, indent=1))


def _status_table(name, rows, totals, writing, left) -> None:
    """The human ``hpcves status``: one line per case, the totals, what is left."""
    from hpcves.run.store import ENDED_NAMES
    from hpcves.run.verdict import DAMAGED

    keys = [k for k in rows[0] if k not in ("case", "status", "t", "t_end", "wall", "steps_per_second",
                                            "message")]
    header = ["case", *keys, "status", "t / t_end", "wall", "steps/s", "reason"]
    lines = []
    for r in rows:
        lines.append([r["case"], *(f"{r[k]:g}" if isinstance(r[k], float) else r[k] or "-" for k in keys), r["status"],
                      f"{r['t']:.4g} / {r['t_end']:.4g}",
                      _duration(r["wall"]) if r["wall"] > 0 else "-",
                      f"{r['steps_per_second']:,.0f}" if r["steps_per_second"] > 0 else "-",
                      (r["message"].splitlines() or [""])[0][:80]])
    widths = [max(len(str(x)) for x in column) for column in zip(header, *lines)]
    for line in [header, *lines]:
        click.echo("  ".join(str(x).ljust(w) for x, w in zip(line, widths)).rstrip())
    readable = [r for r in rows if r["status"] != DAMAGED]
    # a case that ended (finished, decided early, failed, at the model's limit) has done its share, whatever its t
    done = sum(r["t_end"] if r["status"] in ENDED_NAMES else min(r["t"], r["t_end"]) for r in readable)
    total = sum(r["t_end"] for r in readable)
    wall = sum(r["wall"] for r in readable)
    early = sum(1 for r in readable if r["status"] in ENDED_NAMES and r["t"] < r["t_end"])
    share = (f"{100 * done / total:.0f} % done" if total > 0 else "- done") + (
        f" ({early} case{'s' * (early != 1)} ended before t_end: decided, failed or at the model's limit)"
        if early else "")
    if left is None:
        state = ""
    elif left.complete:
        state = "; complete" + (f", {left.failed} failed (--resume --retry-failed reruns them)" if left.failed else "")
    else:
        state = f"; work left: {left.left}"
    click.echo(f"study {name!r}: {len(rows)} cases: " + ", ".join(f"{n} {s}" for s, n in totals.items())
               + f"; simulated time {share}; {_duration(wall)} of compute; {writing}{state}")


def _case_selection(which: str):
    """--case-figures: a named selection, or the case ids of a comma-separated list."""
    from hpcves.reports.case_pages import SELECTIONS

    return which if which in SELECTIONS else [c.strip() for c in which.split(",") if c.strip()]


@main.command("analyze")
@click.argument("file", type=click.Path())
@click.option("--out", "out", type=click.Path(),
              help="Directory for the tables and figures (default: <file>_analysis next to the file).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a threshold of the classification, e.g. --set min_cycles=5 (see [analysis]).")
@click.option("--axes", help="The two parameters of the phase diagrams, e.g. shear_rate,psi_bar.")
@click.option("--no-write-back", is_flag=True, help="Do not store the results in the file's analysis/ group.")
@click.option("--case-figures", "which", default="auto", show_default=True,
              metavar="auto|all|flagged|none|ID,...",
              help="Whose one-page figures to draw: auto (every case's up to 100 cases, else the first 100 "
                   "flagged ones'), every case's, the flagged ones' (undecided, failed, unfinished), none, or "
                   "these case ids' (about 3 s a page, 1 s without streamlines).")
@click.option("--no-case-figures", is_flag=True, help="Same as --case-figures none.")
@click.option("--no-streamlines", is_flag=True,
              help="Case figures without the streamlines around the shapes (about 2 s a case less).")
@click.option("--jobs", "-j", type=click.IntRange(min=1), default=1, show_default=True,
              help="Processes that draw the case figures.")
@click.option("--markers", is_flag=True,
              help="Draw the cases as markers on the figures for a paper too (a search's or refinement's "
                   "phase diagrams; phase_diagram*_cases always shows every case).")
@clean_errors
def analyze_command(file, out, overrides, axes, no_write_back, which, no_case_figures, no_streamlines, jobs,
                    markers):
    """Regimes (TT / PT / TU / undecided), periods, tables and figures of a campaign or run file.

    Writes regimes.csv, regimes.md, periods.md, phase diagrams and period
    tables (PNG and PDF) and cases/<id>.png -- for a [search] campaign,
    critical_shear.csv/.md and S_C figures instead of the period tables (critical_lambda.csv/.md
    and lambda_C for a search along the viscosity ratio), for a
    [refine] campaign boundaries.csv (the polylines) and refinement.md; the
    results also go into the file's analysis/ group. The file may belong to a running campaign (then
    nothing is written into it).
    """
    from hpcves.reports.analyze import analyze, parse_overrides

    axes_pair = None
    if axes:
        axes_pair = tuple(k.strip() for k in axes.split(","))
        if len(axes_pair) != 2:
            raise ConfigError(f"--axes {axes!r}: give two parameters, e.g. shear_rate,psi_bar")
    line = _StatusLine()
    try:
        report = analyze(file, out, overrides=parse_overrides(overrides), write_to_file=not no_write_back,
                         case_figures="none" if no_case_figures else _case_selection(which), axes=axes_pair,
                         streamlines=not no_streamlines, jobs=jobs, markers=markers,
                         progress=lambda text: line.due(0.2) and line.show(text))
    finally:
        line.close()
    rows = report.rows
    for row in rows:
        period = ""
        if row["regime"] in ("PT", "TU") and row["period"] == row["period"]:
            error, dominant = accuracy.error_bar(row, "period")
            period = f"  T = {row['period']:.5g} +- {error:.1g} [{dominant}]"
        click.echo(f"{row['case']}  {row['regime']:<9}{period}  {row['reason']}")
    counts = ", ".join(f"{n} {r}" for r, n in report.counts().items())
    click.echo(f"{report.source.path}: {len(rows)} case{'s' * (len(rows) != 1)}: {counts}")
    for s in report.searches:
        where = f"psi_bar = {s['psi_bar']:g}, Delta = {s['excess_length']:g}, B2 = {s['B2']:g}"
        column = "S_C" if "S_C" in s else "lambda_C"
        if column == "lambda_C":
            where += f", S = {s['shear_rate']:g}"
        value = f"{column} = {s[column]:.4g}" if s[column] == s[column] else s["status"]
        click.echo(f"search {where}: {value}  ({s['reason']})")
    from hpcves.reports.refinement import REFINEMENT_FIELDS

    for r in report.refinements:
        where = ", ".join(f"{k} = {r[k]:g}" for k in r if k not in REFINEMENT_FIELDS)
        click.echo(f"refinement{' ' + where if where else ''}: {r['status']}, {r['cases']} cases "
                   + (f"({r['run_again']} run again) " if r.get("run_again") else "")
                   + f"({r['crossings']} crossings, {r['blurry']} blurry)  ({r['reason']})")
    if report.wrote_back:
        click.echo(f"results stored in {report.source.path} (group analysis/)")
    elif report.note:
        click.echo(report.note, err=True)
    directory = report.written[0].parent
    click.echo(f"tables and figures in {directory}/: " + ", ".join(p.name for p in report.written))
    damaged = report.damaged
    if damaged:
        _fail(f"{report.source.path}: {len(damaged)} damaged case{'s' * (len(damaged) != 1)}, analysed as "
              f"undecided (" + "; ".join(f"{c.case_id}: {c.message}" for c in damaged[:3])
              + (f"; {len(damaged) - 3} more" if len(damaged) > 3 else "") + ")")


@main.command("shapes")
@click.argument("file", type=click.Path())
@click.option("--case", "case_ids", multiple=True, metavar="ID", help="A case to draw (repeat for more rows).")
@click.option("--where", "where", multiple=True, metavar="KEY=VALUE",
              help="Draw every case with this parameter value, e.g. --where psi_bar=0.5 (repeatable).")
@click.option("--out", "out", type=click.Path(), help="The figure (PNG or PDF; default <file>_shapes.png).")
@click.option("--shapes", "n_shapes", type=click.IntRange(1, 12), default=6, show_default=True,
              help="Shapes per row.")
@click.option("--no-streamlines", is_flag=True, help="Shapes only (faster).")
@clean_errors
def shapes_command(file, case_ids, where, out, n_shapes, no_streamlines):
    """Shape sequences: one row per case, shapes coloured by psi over its last period, with the
    streamlines around them. Choose the rows by --case or --where (sorted by shear rate)."""
    from pathlib import Path

    from hpcves.reports.figures import choose, parse_where, shape_sequence_figure

    check_output_path(file)
    if case_ids and where:
        raise ConfigError("--case and --where: choose the cases one way")
    if not case_ids and not where:
        raise ConfigError("choose the cases: --case ID (repeatable) or --where KEY=VALUE, e.g. --where psi_bar=0.5")
    chosen = choose(file, case_ids, parse_where(where))
    target = Path(out) if out else Path(file).with_name(f"{Path(file).stem}_shapes.png")
    fig = shape_sequence_figure(chosen, n_shapes, streamlines=not no_streamlines)
    fig.savefig(target, dpi=130)
    click.echo(f"{target}: {len(chosen)} row{'s' * (len(chosen) != 1)} ("
               + ", ".join(f"{c.case_id} {c.row['regime']}" for c in chosen) + ")")


@main.command("animate")
@click.argument("file", type=click.Path())
@click.option("--case", "case_id", metavar="ID", help="The case of a campaign file to animate.")
@click.option("--out", "out", type=click.Path(),
              help="The movie: .mp4 (needs ffmpeg) or .gif (default <file>_<case>.mp4, or .gif without ffmpeg).")
@click.option("--fps", type=click.IntRange(1, 60), default=12, show_default=True, help="Frames per second.")
@click.option("--no-streamlines", is_flag=True, help="Shapes only (faster).")
@clean_errors
def animate_command(file, case_id, out, fps, no_streamlines):
    """An animation of one case, one frame per snapshot: the shape coloured by psi with the
    streamlines around it, beside theta(t)."""
    from pathlib import Path

    from hpcves.reports.figures import choose, default_movie, write_animation

    check_output_path(file)
    chosen = choose(file, (case_id,) if case_id else (), one=True)[0]
    target = Path(out) if out else default_movie(Path(file), chosen.case_id)
    line = _StatusLine()
    try:
        frames = write_animation(chosen, target, fps, streamlines=not no_streamlines,
                                 progress=lambda i, n: line.due(0.2) and line.show(f"frame {i}/{n}"))
    finally:
        line.close()
    click.echo(f"{target}: {frames} frames at {fps} per second (case {chosen.case_id}, {chosen.row['regime']})")
    if frames < 2 * fps:
        click.echo(f"  one frame per snapshot: a smoother movie needs a smaller run.snapshot_interval "
                   f"(this case has {frames} snapshots)", err=True)


if __name__ == "__main__":     # pragma: no cover
    main()
