"""The ``hpcves`` command line.

Exit status: 0 done (or stopped cleanly with a checkpoint written),
1 the computation failed (diverged), 2 bad input (configuration, files).
"""
from __future__ import annotations

import functools
import os
import signal
import sys
import time

import click

from . import __version__
from .params import ConfigError


def _fail(message: str) -> None:
    click.echo(f"Error: {message}", err=True)
    sys.exit(2)


def clean_errors(func):
    """Bad input of any kind: one line on stderr, exit status 2, no traceback."""
    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except ConfigError as exc:          # includes checkpoint.FileFormatError
            _fail(str(exc))
    return wrapper


class ProgressLine:
    """``t = 0.512 / 5  |  1043 steps/s  |  ETA 4 s  |  theta = 0.581`` on stderr.

    Rewritten in place on a terminal; on a pipe or log file, one line every 30 s.
    """

    def __init__(self, label: str = "", stream=sys.stderr):
        self.label = label
        self.stream = stream
        self.tty = stream.isatty()
        self._last_line = 0.0
        self._width = 0

    def __call__(self, tick) -> None:
        eta = _duration(tick.eta_seconds)
        text = (f"{self.label}t = {tick.t:.4g} / {tick.t_end:.4g}  |  {tick.steps_per_second:,.0f} steps/s"
                f"  |  ETA {eta}  |  theta = {tick.theta:.4f}")
        if self.tty:
            self.stream.write("\r" + text.ljust(self._width))
            self._width = len(text)
            self.stream.flush()
        elif time.monotonic() - self._last_line >= 30.0:
            self._last_line = time.monotonic()
            self.stream.write(text + "\n")
            self.stream.flush()

    def close(self) -> None:
        if self.tty and self._width:
            self.stream.write("\n")
            self.stream.flush()


def _duration(seconds: float) -> str:
    if seconds != seconds or seconds == float("inf"):
        return "?"
    seconds = int(round(seconds))
    if seconds < 120:
        return f"{seconds} s"
    if seconds < 7200:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {(seconds % 3600) // 60:02d} min"


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


@click.group()
@click.version_option(__version__, prog_name="hpcves")
def main():
    """Two-phase vesicles in shear flow: simulations, campaigns, analysis."""


@main.command("run")
@click.argument("case_file", required=False, type=click.Path(dir_okay=False))
@click.option("--out", "out", type=click.Path(dir_okay=False), help="HDF5 file to write (new).")
@click.option("--resume", "resume", type=click.Path(dir_okay=False),
              help="Continue the run in this HDF5 file from its last checkpoint.")
@click.option("--overwrite", is_flag=True, help="Replace an existing --out file.")
@click.option("--quiet", is_flag=True, help="No progress line.")
@clean_errors
def run_command(case_file, out, resume, overwrite, quiet):
    """Run one case: ``hpcves run CASE.toml --out case.h5`` or ``hpcves run --resume case.h5``."""
    from . import runner
    from .checkpoint import FAILED, FINISHED, STATUS_NAMES, CaseStore, open_file
    from .config import load_case

    if resume and (case_file or out):
        raise click.UsageError("--resume FILE takes the case from the file; give no CASE_FILE or --out")
    if not resume and not (case_file and out):
        raise click.UsageError("give CASE_FILE and --out FILE, or --resume FILE")

    if resume:
        path = resume
        h5 = open_file(path, "r+")
        store = CaseStore.open(h5, where=path)
        if store.status == FINISHED:
            t_done = store.progress[0]
            h5.close()
            click.echo(f"{path}: finished already (t = {t_done:.6g}); nothing to do.")
            return
    else:
        case = load_case(case_file)
        path = out
        if overwrite and os.path.exists(path):
            os.remove(path)
        h5 = open_file(path, "w-")
        store = CaseStore.create(h5, case)
    case = store.case
    click.echo(f"{path}: N = {case.numerics.N}, dt = {case.numerics.dt:g}, t_end = {case.run.t_end:g}, "
               f"S = {case.physics.shear_rate:g}, psi_bar = {case.physics.psi_bar:g}, "
               f"excess length = {case.physics.excess_length:g}" + ("  (resuming)" if resume else ""),
               err=True)
    progress = None if quiet else ProgressLine()
    try:
        with StopFlag() as stop:
            outcome = runner.run(store, h5.flush, resume=bool(resume), progress=progress,
                                 stop_requested=stop)
    finally:
        if progress is not None:
            progress.close()
        h5.close()
    rate = outcome.steps / outcome.wall if outcome.wall > 0 else 0.0
    summary = (f"{path}: {STATUS_NAMES[outcome.status]} at t = {outcome.t:.6g} "
               f"({outcome.steps} steps in {_duration(outcome.wall)}, {rate:,.0f} steps/s)")
    if outcome.status == FAILED:
        click.echo(summary + f"\n{outcome.message}", err=True)
        sys.exit(1)
    if outcome.status != FINISHED:
        summary += f"; resume with: hpcves run --resume {path}"
    click.echo(summary)


if __name__ == "__main__":     # pragma: no cover
    main()
