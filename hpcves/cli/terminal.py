"""What the command line shows and hears: error lines and exit status 2, the status and progress
lines on stderr, the library's log records, and the signals that stop a run at a checkpoint."""
from __future__ import annotations

import functools
import logging
import os
import signal
import sys
import time

import click

from hpcves.errors import HpcvesError


def error(message) -> None:
    """``Error: <problem>`` on stderr, a line for each problem (a file's problems come together:
    config.Problems)."""
    for line in str(message).splitlines() or [""]:
        click.echo(f"Error: {line}", err=True)


def fail(message: str) -> None:
    """error, and exit status 2."""
    error(message)
    sys.exit(2)


class OneLinePath(click.Path):
    """A file argument or option that refuses a name with a line break or another control character,
    in one line and exit status 2: every message, table and batch script names files on one line."""

    def convert(self, value, param, ctx):
        text = os.fsdecode(value) if isinstance(value, bytes) else str(value)
        if any(ord(c) < 32 or ord(c) == 127 for c in text):
            fail(f"{text!r}: the name holds a line break or another control character; rename it (hpcves "
                 "names files in one-line messages and batch scripts)")
        return super().convert(value, param, ctx)


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
            fail(str(exc))
        except OSError as exc:              # a full disk, permissions, a directory where a file belongs
            fail(os_error_text(exc))
    return wrapper


#: the MPI launchers that hand a rank's stderr to their own over a pipe (Open MPI's names, MPICH's)
LAUNCHERS = ("mpirun", "mpiexec", "orterun", "prterun", "mpiexec.hydra", "hydra_pmi_proxy")


def _process(pid: int) -> tuple[str, int, str]:
    """(name, parent pid, where its stderr goes) of a process, from Linux's /proc ('', 0, '' elsewhere)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            stat = f.read()
        name, rest = stat[stat.index("(") + 1:stat.rindex(")")], stat[stat.rindex(")") + 2:].split()
        try:
            target = os.readlink(f"/proc/{pid}/fd/2")
        except OSError:
            target = ""
        return name, int(rest[1]), target
    except (OSError, ValueError, IndexError):
        return "", 0, ""


def interactive(stream) -> bool:
    """Whether ``stream`` reaches a person at a terminal: a TTY itself, or -- under mpirun, which hands a
    rank's stderr on through a pipe -- the launcher above this process writes to one (its stderr, read
    from /proc, is a terminal device). A batch job's launcher writes to its log: not interactive.
    ``HPCVES_PROGRESS=tty`` or ``=log`` says which, where this guesses wrong."""
    chosen = os.environ.get("HPCVES_PROGRESS", "").strip().lower()
    if chosen in ("tty", "log"):
        return chosen == "tty"
    try:
        if stream.isatty():
            return True
    except (AttributeError, ValueError):
        return False
    pid = os.getppid()
    for _ in range(3):                       # the rank's parent, or a proxy's (MPICH's hydra)
        name, parent, stderr = _process(pid)
        if name in LAUNCHERS:
            return stderr.startswith(("/dev/pts/", "/dev/tty")) and not stderr.startswith("/dev/ttyS")
        if not parent:
            break
        pid = parent
    return False


class StatusLine:
    """One status line on stderr: rewritten in place on a terminal (also under mpirun started from
    one: :func:`interactive`); on a pipe or a log file, written as a new line at most every LOG_SECONDS."""

    LOG_SECONDS = 30.0

    def __init__(self, stream=sys.stderr):
        self.stream = stream
        self.tty = interactive(stream)
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


class ProgressLine(StatusLine):
    """``t = 0.512 / 5  |  1043 steps/s  |  ETA 4 s  |  theta = 0.581`` on stderr."""

    def __init__(self, label: str = "", stream=sys.stderr):
        super().__init__(stream)
        self.label = label

    def __call__(self, tick) -> None:
        if self.due():
            self.show(f"{self.label}t = {tick.t:.4g} / {tick.t_end:.4g}  |  {tick.steps_per_second:,.0f} steps/s"
                      f"  |  ETA {duration(tick.eta_seconds)}  |  theta = {tick.theta:.4f}")


def compiling() -> bool:
    """Whether the first step of this process will compile the solver's kernels (numba's cache is cold)."""
    from hpcves.solver.compiled import cache_is_warm

    return cache_is_warm() is False


def duration(seconds: float) -> str:
    if seconds != seconds or seconds == float("inf"):
        return "?"
    seconds = int(round(seconds))
    if seconds < 120:
        return f"{seconds} s"
    if seconds < 7200:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {(seconds % 3600) // 60:02d} min"


class SigtermSeen:
    """A SIGTERM handler that only notes the signal; the work polls it and ends at a point of its own
    choosing: an exception raised in the handler lands wherever the signal did, and inside a finalizer
    (a weakref callback during garbage collection) Python prints it and goes on."""

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


class TerminalLog(logging.Handler):
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


def log_to_terminal() -> None:
    library = logging.getLogger("hpcves")
    if not any(isinstance(h, TerminalLog) for h in library.handlers):
        library.addHandler(TerminalLog())
        library.setLevel(logging.INFO)
        library.propagate = False


class CampaignProgress(StatusLine):
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
        """Show ``stage``, a campaign.scheduler.StageProgress."""
        if not self.due(0.5):
            return
        elapsed = time.monotonic() - self.start
        fraction = stage.fraction
        eta = elapsed * (1.0 - fraction) / fraction if fraction > 0.0 else float("inf")
        bar = "#" * int(round(20 * fraction))
        self.show(f"[{bar:<20}] {self.n_done_before + stage.ended}/{self.n_total} cases | "
                  f"{stage.running} running | {self.n_failed_before + stage.failed} failed | {100 * fraction:.0f} % | "
                  f"ETA {duration(eta)}")
