"""Running a study on MPI: rank 0 schedules and computes, the other ranks compute.

Scheduling (:class:`Master`, rank 0). Cases go out most expensive first
(cost = steps x N^2) to whichever rank asks. Rank 0 runs cases itself: its
run loop polls the message queue once per time step (``MPI.Iprobe``, ~1 us)
and answers requests there, so with ``mpirun -n 2`` on two cores both cores
compute. Nobody busy-waits: a rank with nothing to compute polls with a
sleep that backs off from 1 ms to 50 ms (as mpi4py.futures does), and the
final synchronisation is a non-blocking barrier polled the same way.

Workers (:func:`worker_loop`) ask for a case, run it, report, ask again.
A case that raises is recorded as failed (message and traceback in the file)
and the rank asks for the next one; only an error outside a case (a bug in
the scheduler itself) aborts the job (``MPI.Abort``), so nothing ever hangs.

Stopping. SIGTERM/SIGINT on any rank (SLURM signals every task; mpirun
forwards to every rank) sets that rank's flag; its running case checkpoints
at the next step and reports "interrupted", and rank 0 then stops handing
out cases and tells every busy rank to checkpoint too. If the job has not
wound down ``stop_timeout`` seconds after the first stop request, rank 0
aborts it (valid checkpoints are never at risk: see checkpoint.py).

File access. With one process the file is opened with the default driver.
With several ranks and an h5py built with MPI every rank opens it with the
``mpio`` driver; the structure is created collectively up front and flushed,
after which each case is written only by the rank running it (independent
raw-data writes to preallocated datasets, which reach the file in program
order -- the order the checkpoint protocol needs). Without MPI in h5py (or
with ``io="relay"``) only rank 0 opens the file and applies the other ranks'
writes, which they send it in order (relay.py).
"""
from __future__ import annotations

import fcntl
import os
import socket
import sys
import threading
import time
import traceback
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from . import runner
from .campaign_file import CampaignFile
from .checkpoint import (FAILED, FINISHED, INTERRUPTED, PENDING, STATUS_NAMES, FileFormatError, attr_text,
                         open_file)
from .params import ConfigError
from .relay import Relay, RemoteCampaign
from .search_campaign import SearchDriver, cases_from_file
from .study import Study

TAG_REQUEST = 11      # worker -> rank 0: ("ready",) | ("done", CaseResult) | ("progress", id, fraction) | ("stop",)
                      #   | with --io relay, its file writes and reads (relay.py), on this tag to keep their order
TAG_TASK = 12         # rank 0 -> worker: (case_id, resume) or None (no more work)
TAG_STOP = 13         # rank 0 -> worker: checkpoint the running case and report
TAG_REPLY = 14        # rank 0 -> worker: the answer to a file read (--io relay only)
IO_MODES = ("auto", "mpio", "relay")
PROGRESS_SECONDS = 2.0


@dataclass(frozen=True)
class CaseResult:
    case_id: str
    status: int
    message: str
    t: float
    steps: int
    wall: float
    rank: int


@dataclass(frozen=True)
class Summary:
    """What a campaign call did, and the state of the whole file afterwards."""

    ran: tuple                      # CaseResult of every case run in this call
    counts: dict                    # status name -> number of cases in the file
    failed: tuple                   # (case_id, message) of every failed case in the file
    wall: float
    searches: tuple = ()            # search studies: SearchOutcome of every search (empty if stopped)

    @property
    def exit_status(self) -> int:
        return 1 if self.failed else 0


# ---------------------------------------------------------------------- helpers
class Backoff:
    """Sleep 1 ms, doubling to 50 ms, while there is nothing to do; reset on activity."""

    def __init__(self, start=1e-3, limit=0.05):
        self.start, self.limit, self.delay = start, limit, start

    def reset(self):
        self.delay = self.start

    def sleep(self):
        time.sleep(self.delay)
        self.delay = min(2.0 * self.delay, self.limit)


def wait_until(ready: Callable[[], bool]) -> None:
    """Poll ``ready`` with a backoff until it is true (MPI's own waits keep a core spinning)."""
    backoff = Backoff()
    while not ready():
        backoff.sleep()


def wait(request) -> None:
    """Complete a non-blocking MPI request without spinning."""
    wait_until(request.Test)


class CampaignLock:
    """An exclusive flock on ``<output>.lock``, held for the whole campaign.

    The kernel drops it when the process dies, even by SIGKILL, so a killed
    campaign can always be resumed; a second campaign on the same file while
    the first runs is refused with the holder's pid and host.
    """

    def __init__(self, path: Path):
        self.path = Path(str(path) + ".lock")
        self._fd = None

    def acquire(self) -> "CampaignLock":
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 200, 0).decode(errors="replace").strip() or "another process"
            os.close(fd)
            raise FileFormatError(f"{str(self.path)[:-5]}: a campaign is already running on this file "
                                  f"({holder}); wait for it or stop it first") from None
        except OSError as exc:            # a file system without flock: go on, but say so
            print(f"warning: cannot lock {self.path} ({exc.strerror}); make sure no other campaign "
                  "writes this file", file=sys.stderr)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()}, since {time.strftime('%Y-%m-%d %H:%M:%S')}"
                  .encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            os.ftruncate(self._fd, 0)
            os.close(self._fd)          # closing drops the lock; the empty file stays (see docs)
            self._fd = None


def prepare_file(study: Study, path: Path, *, resume: bool, overwrite: bool) -> str:
    """Decide, on rank 0 and serially, whether to create the file or continue it; refuse bad files.

    Returns "create" or "continue".
    """
    if path.exists() and overwrite:
        path.unlink()
    if not path.exists():
        return "create"
    if not resume:
        raise FileFormatError(f"{path}: exists already; use --resume to continue it or --overwrite to start over")
    with open_file(path, "r", locking=False) as h5:
        partial = (attr_text(h5.attrs.get("mode", "")) == "search"
                   and len(h5.get("cases", ())) != int(h5.attrs.get("n_cases", -1)))
    if partial:                 # killed while adding a stage's cases: those cases are made again
        with open_file(path, "r+") as h5:
            dropped = CampaignFile.drop_partial_stage(h5)
        print(f"{path}: removed {dropped} case{'s' * (dropped != 1)} of a search stage whose adding was "
              "interrupted; the search makes them again", file=sys.stderr)
    with open_file(path, "r", locking=False) as h5:
        try:
            campaign = CampaignFile.check(h5, str(path))
            campaign.check_study(study, str(path))
            for case_id in campaign.case_ids:     # every case readable (a damaged file fails here)
                campaign.store(case_id).status
        except (OSError, KeyError, ValueError) as exc:
            if isinstance(exc, ConfigError):
                raise
            raise FileFormatError(f"{path}: damaged campaign file ({type(exc).__name__}: {exc})") from None
    return "continue"


def work_list(campaign: CampaignFile, study: Study, retry_failed: bool) -> list[tuple[str, bool]]:
    """(case_id, resume) for every case to run, most expensive first.

    Finished cases are skipped; failed ones too, unless ``retry_failed`` (then
    they start over); everything else continues from its last valid checkpoint.
    """
    todo = []
    for case_id, status in campaign.statuses().items():
        if status == FINISHED or (status == FAILED and not retry_failed):
            continue
        todo.append((case_id, status != FAILED))
    todo.sort(key=lambda item: (-study.by_id(item[0]).cost, item[0]))
    return todo


def run_one(campaign: CampaignFile, case_id: str, resume: bool, flush: Callable[[], None], rank: int,
            stop_requested: Callable[[], bool], progress: Callable[[float], None]) -> CaseResult:
    """Run one case to its end (or to a stop request); an exception is recorded, never raised."""
    store = campaign.store(case_id)
    t0 = time.perf_counter()

    def tick(t):
        progress(t.t / t.t_end)

    try:
        out = runner.run(store, flush, resume=resume, progress=tick, stop_requested=stop_requested)
        return CaseResult(case_id, out.status, out.message, out.t, out.steps, out.wall, rank)
    except Exception as exc:                     # noqa: BLE001 -- recorded in the file, the campaign goes on
        message = f"{type(exc).__name__}: {exc}"
        store.set_status(FAILED, message, traceback.format_exc())
        flush()
        return CaseResult(case_id, FAILED, message, float("nan"), 0, time.perf_counter() - t0, rank)


# ---------------------------------------------------------------------- rank 0
class Master:
    """Hands out cases, runs cases itself between scheduling turns, shows progress."""

    def __init__(self, comm, campaign: CampaignFile, study: Study, todo, flush, stop_flag,
                 stop_timeout: float, display=None, relay: Relay | None = None):
        self.comm = comm
        self.relay = relay                       # applies the other ranks' file writes (--io relay)
        self.size = 1 if comm is None else comm.Get_size()
        self.campaign, self.study, self.flush = campaign, study, flush
        self.pending = deque(todo)
        self.stop_flag = stop_flag
        self.stop_timeout = stop_timeout
        self.display = display
        self.busy: dict[int, str] = {}           # rank -> case id
        self.fraction: dict[str, float] = {}     # case id -> fraction of its t_end reached
        self.waiting: set[int] = set()
        self.results: list[CaseResult] = []
        self.stopping = False
        self.cost_total = sum(study.by_id(c).cost for c, _ in todo)
        if self.size > 1:
            from mpi4py import MPI

            self._status, self._any_source = MPI.Status(), MPI.ANY_SOURCE

    # -- messages
    def service(self) -> bool:
        """Answer every waiting message; hand out cases. Returns True if anything happened."""
        active = False
        if self.stop_flag() and not self.stopping:
            self.begin_stop("signal")
        if self.size > 1:
            status = self._status
            while self.comm.Iprobe(source=self._any_source, tag=TAG_REQUEST, status=status):
                source = status.Get_source()
                message = self.comm.recv(source=source, tag=TAG_REQUEST)
                active = True
                kind = message[0]
                if self.relay is not None and kind in Relay.KINDS:
                    self.relay.handle(self.comm, source, message)
                    continue
                if kind == "progress":
                    self.fraction[message[1]] = message[2]
                    continue
                if kind == "done":
                    self.record(message[1])
                    self.busy.pop(source, None)
                elif kind == "stop":
                    self.begin_stop(f"signal on rank {source}")
                    continue
                self.waiting.add(source)
            for rank in sorted(self.waiting):
                if not self.pending or self.stopping:
                    break
                case_id, resume = self.pending.popleft()
                self.comm.send((case_id, resume), dest=rank, tag=TAG_TASK)
                self.waiting.discard(rank)
                self.busy[rank] = case_id
                self.fraction[case_id] = 0.0
                active = True
        if self.display is not None:
            self.display(self)
        return active

    def record(self, result: CaseResult) -> None:
        self.results.append(result)
        self.fraction[result.case_id] = 1.0 if result.status in (FINISHED, FAILED) else self.fraction.get(
            result.case_id, 0.0)
        if result.status == FAILED:
            first = result.message.splitlines()[0] if result.message else ""
            print(f"\ncase {result.case_id} ({self.study.by_id(result.case_id).label()}) failed on rank "
                  f"{result.rank}: {first}", file=sys.stderr)
        if result.status == INTERRUPTED and not self.stopping:
            self.begin_stop(f"rank {result.rank} was stopped")

    def begin_stop(self, why: str) -> None:
        """No new cases; every busy rank checkpoints and reports; abort if that takes too long."""
        if self.stopping:
            return
        self.stopping = True
        print(f"\nstopping ({why}): checkpointing the running cases", file=sys.stderr)
        if self.size > 1:
            for rank in self.busy:
                if rank != 0:
                    self.comm.send(None, dest=rank, tag=TAG_STOP)
            threading.Thread(target=self._watchdog, daemon=True).start()

    def _watchdog(self) -> None:
        time.sleep(self.stop_timeout)
        print(f"\nthe campaign did not stop within {self.stop_timeout:g} s of the stop request; aborting "
              "(every case keeps its last valid checkpoint)", file=sys.stderr, flush=True)
        self.comm.Abort(3)

    def cost_done(self) -> float:
        return sum(self.study.by_id(c).cost * f for c, f in self.fraction.items())

    # -- the loop
    def run(self) -> list[CaseResult]:
        backoff = Backoff()
        while True:
            if self.service():
                backoff.reset()
            if self.pending and not self.stopping:
                case_id, resume = self.pending.popleft()
                self.fraction[case_id] = 0.0
                self.busy[0] = case_id

                def poll() -> bool:
                    self.service()
                    return self.stopping

                def progress(fraction, case_id=case_id):
                    self.fraction[case_id] = fraction

                result = run_one(self.campaign, case_id, resume, self.flush, 0, poll, progress)
                del self.busy[0]
                self.record(result)
                backoff.reset()
            elif not self.busy and len(self.waiting) == self.size - 1:
                break               # every other rank has asked for work: none of its messages is left unread
            else:
                backoff.sleep()
        for rank in range(1, self.size):
            self.comm.send(None, dest=rank, tag=TAG_TASK)
        return self.results


# ---------------------------------------------------------------------- other ranks
def worker_loop(comm, campaign: CampaignFile, flush, stop_flag) -> None:
    """Ask rank 0 for cases and run them until told there are no more."""
    rank = comm.Get_rank()
    comm.send(("ready",), dest=0, tag=TAG_REQUEST)
    told_stop = False
    backoff = Backoff()
    while True:
        if comm.Iprobe(source=0, tag=TAG_TASK):
            task = comm.recv(source=0, tag=TAG_TASK)
            if task is None:
                break
            case_id, resume = task
            last = [0.0]

            def stop_requested() -> bool:
                return stop_flag() or comm.Iprobe(source=0, tag=TAG_STOP)

            def progress(fraction, case_id=case_id):
                now = time.monotonic()
                if now - last[0] >= PROGRESS_SECONDS:
                    last[0] = now
                    comm.send(("progress", case_id, fraction), dest=0, tag=TAG_REQUEST)

            result = run_one(campaign, case_id, resume, flush, rank, stop_requested, progress)
            comm.send(("done", result), dest=0, tag=TAG_REQUEST)
            backoff.reset()
        else:
            if stop_flag() and not told_stop:       # signalled while idle: tell rank 0
                told_stop = True
                comm.send(("stop",), dest=0, tag=TAG_REQUEST)
            backoff.sleep()
    while comm.Iprobe(source=0, tag=TAG_STOP):      # a stop that crossed our last report
        comm.recv(source=0, tag=TAG_STOP)


# ---------------------------------------------------------------------- the whole job
def run_campaign(study: Study, path: Path, comm=None, *, resume: bool = False, retry_failed: bool = False,
                 overwrite: bool = False, io: str = "auto", stop_flag: Callable[[], bool] = lambda: False,
                 display=None, announce: Callable[[str, int, int], None] = lambda text, total, finished: None,
                 on_stage: Callable[[list], None] = lambda outcomes: None) -> Summary:
    """Run (or continue) a study into ``path`` on every rank of ``comm`` (None: this process alone).

    ``io`` (several ranks only): "mpio" -- every rank opens the file with
    h5py's MPI driver; "relay" -- only rank 0 opens it and applies the other
    ranks' writes (relay.py); "auto" -- mpio where h5py has MPI, else relay.

    A search study (``study.search``) runs in stages (search_campaign.py):
    after each, rank 0 classifies the finished cases, the searches choose
    their next shear rates, and every rank adds those cases to the file
    before the next stage runs them. Rank 0 calls ``on_stage(outcomes)`` with
    the state of every search after each stage.

    Rank 0 calls ``announce(text, None, n_finished)`` with the campaign's
    first line, ``announce(text, n_cases, n_finished_before)`` once the work
    of a stage is known, and ``display(master)`` at every scheduling turn.

    Collective: every rank calls it with the same study. Bad input raises
    ConfigError on every rank (the message is rank 0's).
    """
    size = 1 if comm is None else comm.Get_size()
    rank = 0 if comm is None else comm.Get_rank()
    start = time.perf_counter()
    io = choose_io(io, size)
    lock = None
    verdict = None
    if rank == 0:
        try:
            lock = CampaignLock(path).acquire()
            verdict = ("ok", prepare_file(study, path, resume=resume, overwrite=overwrite))
        except ConfigError as exc:
            if lock is not None:
                lock.release()
            verdict = ("error", str(exc))
    if size > 1:
        verdict = comm.bcast(verdict, root=0)
    if verdict[0] == "error":
        raise FileFormatError(verdict[1])
    mode = verdict[1]

    try:
        h5, campaign, flush = _open(study, path, comm, mode, io)
        try:
            results, outcomes = [], []
            driver = None
            if rank == 0 and study.search is not None:
                driver = SearchDriver(study)
                if mode == "continue":
                    study = cases_from_file(study, campaign)
            stage = 0
            while True:
                ran, stopped = _run_stage(study, path, comm, campaign, flush, io, mode, stage,
                                          retry_failed and stage == 0, stop_flag, display, announce)
                results += ran
                if study.search is None:
                    break
                if io == "mpio":
                    # Rank 0 is about to read the cases the others wrote: MPI-IO makes their writes
                    # visible after a sync by the writers (H5Fflush, collective) and a barrier.
                    h5.flush()
                    comm.Barrier()
                plan = ("stop",)
                if rank == 0 and not stopped:
                    outcomes, new = driver.next_stage(study, campaign)
                    on_stage(outcomes)
                    plan = ("add", new) if new else ("done",)
                if size > 1:
                    plan = comm.bcast(plan, root=0)
                if plan[0] != "add":
                    break
                study = study.with_cases(plan[1]) if rank == 0 else study
                if io == "mpio":
                    # Adding cases is collective, and parallel HDF5 hangs in it when rank 0 alone has
                    # just read much of the file (classifying): reopening gives every rank the same
                    # metadata cache again.
                    h5.close()
                    h5 = None
                    h5, campaign, flush = _open(study, path, comm, "continue", io)
                    campaign.add_cases(plan[1])
                    h5.flush()
                elif rank == 0:
                    campaign.add_cases(plan[1])
                    flush()
                stage += 1
            summary = None
            if rank == 0:
                counts = {name: 0 for name in STATUS_NAMES.values()}
                failed = []
                for row in campaign.table():
                    counts[row["status"]] += 1
                    if row["status"] == "failed":
                        failed.append((row["case"], row["message"]))
                summary = Summary(tuple(results), counts, tuple(failed), time.perf_counter() - start,
                                  tuple(outcomes))
        finally:
            if h5 is not None:
                h5.close()
        if size > 1:
            summary = comm.bcast(summary, root=0)
        return summary
    finally:
        if lock is not None:
            lock.release()


def _run_stage(study, path, comm, campaign, flush, io, mode, stage, retry_failed, stop_flag, display,
               announce) -> tuple[list[CaseResult], bool]:
    """Run every unfinished case of the file on every rank: (results, whether it was stopped) on rank 0."""
    size = 1 if comm is None else comm.Get_size()
    rank = 0 if comm is None else comm.Get_rank()
    results, stopped = [], False
    if rank == 0:
        todo = work_list(campaign, study, retry_failed)
        statuses = campaign.statuses()
        finished = sum(1 for s in statuses.values() if s == FINISHED)
        if stage == 0:
            announce(_announcement(study, path, statuses, size, mode, io), None, finished)
        if todo or study.search is None:
            announce(_stage_line(study, statuses, todo, stage), len(statuses), finished)
        relay = Relay(campaign, flush, TAG_REPLY) if io == "relay" else None
        master = Master(comm, campaign, study, todo, flush, stop_flag, study.stop_timeout, display, relay)
        results = master.run()
        stopped = master.stopping
    else:
        worker_loop(comm, campaign, flush, stop_flag)
    if size > 1:
        wait(comm.Ibarrier())     # everyone is done writing before the collective close (or the next stage)
    return results, stopped


def choose_io(io: str, size: int) -> str:
    """The file access of a campaign on ``size`` ranks: "serial", "mpio" or "relay"."""
    if io not in IO_MODES:
        raise ConfigError(f"io = {io!r}: choose one of {', '.join(IO_MODES)}")
    if size == 1:
        return "serial"
    import h5py

    has_mpi = h5py.get_config().mpi
    if io == "auto":
        return "mpio" if has_mpi else "relay"
    if io == "mpio" and not has_mpi:
        raise ConfigError("--io mpio: this h5py was built without MPI (make setup builds one with it); "
                          "--io relay works without")
    return io


def _open(study: Study, path: Path, comm, mode: str, io: str):
    """(h5 or None, campaign, flush) on this rank, the file created first if ``mode`` is "create".

    serial: this process alone. mpio: every rank opens the file and creates
    the structure collectively; then raw writes reach the file at once, in
    program order, so ``flush`` has nothing to do (File.flush would be
    collective). relay: rank 0 opens it and tells the others whether that
    worked; they get a RemoteCampaign.
    """
    rank = 0 if comm is None else comm.Get_rank()
    if io == "relay" and rank > 0:
        opened = comm.bcast(None, root=0)
        if opened is not None:
            raise FileFormatError(opened)
        remote = RemoteCampaign(comm, TAG_REQUEST, TAG_REPLY, wait_until)
        return None, remote, remote.flush
    h5 = None
    try:
        if io == "mpio":
            h5 = open_file(path, "w" if mode == "create" else "r+", driver="mpio", comm=comm)
        else:
            h5 = open_file(path, "w" if mode == "create" else "r+")
        if mode == "create":
            campaign = CampaignFile.create(h5, study)
            h5.flush()                 # (collective under mpio) the structure is on disk before any case runs
        else:
            campaign = CampaignFile(h5)
    except ConfigError as exc:
        if h5 is not None:
            h5.close()
        if io == "relay":
            comm.bcast(str(exc), root=0)
        raise
    if io == "relay":
        comm.bcast(None, root=0)
    return h5, campaign, (h5.flush if io != "mpio" else _nothing)


def _nothing() -> None:
    pass


def _announcement(study, path, statuses, size, mode, io) -> str:
    """The first line of a campaign: what, where, on how many ranks."""
    access = {"serial": "serial HDF5", "mpio": "parallel HDF5", "relay": "HDF5 through rank 0"}[io]
    verb = "new file" if mode == "create" else "continuing"
    if study.search is None:
        what = f"{len(study.cases)} cases"
    else:
        n = len(study.searches)
        what = (f"{n} critical-shear search{'es' * (n != 1)} over S in [{study.search.low:g}, "
                f"{study.search.high:g}] to {study.search.rel_tol:g} (at most {study.search.max_cases} cases each), "
                f"{len(statuses)} cases so far")
    return f"campaign {study.name!r} -> {path} ({verb}): {what}; {size} rank{'s' * (size > 1)}, {access}"


def _stage_line(study, statuses, todo, stage) -> str:
    """What a stage runs: cases to run, resumed, finished and failed before."""
    finished = sum(1 for s in statuses.values() if s == FINISHED)
    failed = sum(1 for s in statuses.values() if s == FAILED)
    resumed = sum(1 for case_id, resume in todo if resume and statuses[case_id] != PENDING)
    parts = [f"{len(todo)} to run"]
    if resumed:
        parts.append(f"{resumed} from a checkpoint")
    if finished:
        parts.append(f"{finished} finished before")
    if failed:
        parts.append(f"{failed} failed before" + ("" if any(not r for _, r in todo) else
                                                  " (--retry-failed reruns them)"))
    if study.search is not None and stage > 0:
        searches = len({study.by_id(case_id).search for case_id, _ in todo})
        parts[0] = f"stage {stage}: {len(todo)} new case{'s' * (len(todo) != 1)} for {searches} " \
                   f"search{'es' * (searches != 1)}"
    return ", ".join(parts)
