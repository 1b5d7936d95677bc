"""Running a study on MPI: rank 0 schedules and computes, the other ranks compute.

Scheduling (:class:`Master`, rank 0). Cases go out most expensive first
(cost = steps x N^2) to whichever rank asks. On up to 4 ranks (queue.RANK0_COMPUTES_UP_TO)
rank 0 runs cases itself: its run loop polls the message queue once per time step
(``MPI.Iprobe``, ~1 us) and answers requests there, so with ``mpirun -n 2`` on two
cores both cores compute. On more ranks it only schedules (and, under relay, writes
for everyone): a time step between its answers holds up every other rank, and the
answers of a whole job add up to more than a worker's computing (under relay at
-n 8, rank 0 running cases too used 7x a worker's CPU and set the pace). Nobody busy-waits: a rank
with nothing to compute polls with a
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
aborts it (valid checkpoints are never at risk: see run/store.py).

File access. With one process the file is opened with the default driver.
With several ranks and an h5py built with MPI every rank opens it with the
``mpio`` driver; the structure is laid out up front by rank 0 alone with serial
HDF5 (collective creation of every object made it ~20x slower on 8 ranks), under a
temporary name that is renamed to the file's once complete (atomic.py), after
which each case is written only by the rank running it (independent raw-data
writes to preallocated datasets, which reach the file in program order -- the
order the checkpoint protocol needs). A search or refine stage's new cases are added
the same way, to a copy that replaces the file. Without MPI in h5py (or with
``io="relay"``) only rank 0 opens the file and applies the other ranks'
writes, which they send it in order (relay.py). Each mode is one object with
the same methods (access.py); the driver asks it, never tests the mode.

Who writes. Every rank holds its part of the file's lock (lock.py) for the
whole campaign, so no second campaign starts while any rank of this one
lives. When the file system refuses a write (a full disk), the case is not
failed: the campaign stops as on SIGTERM, every case keeping its last valid
checkpoint, and ends with exit status 2 and the reason.
"""
from __future__ import annotations

import logging
import threading
import time
import traceback
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

from hpcves.analysis.regimes import AnalysisSettings
from hpcves.campaign.access import FileAccess, choose_io, file_access
from hpcves.campaign.file import CampaignFile
from hpcves.campaign.growth import Growth, growth
from hpcves.campaign.polling import Backoff, bcast, wait
from hpcves.campaign.queue import Task, WorkQueue, computing_ranks
from hpcves.campaign.refine_stages import RefineDriver, run_again
from hpcves.campaign.relay import Relay, RemoteCampaign, RemoteCaseStore
from hpcves.campaign.search_stages import SearchDriver
from hpcves.campaign.study import Study
from hpcves.errors import HpcvesError
from hpcves.files import faults
from hpcves.files.atomic import (
    METADATA_BYTES_PER_FILE,
    StorageError,
    copy_for_change,
    new_partial,
    partial_path,
    publish,
    remove_partial,
    require_space,
    size_text,
)
from hpcves.files.lock import CampaignLock, LockError, real_path
from hpcves.run import runner
from hpcves.run.store import (
    ENDED,
    FAILED,
    FINISHED,
    HDF5_ERRORS,
    INTERRUPTED,
    MODEL_LIMIT,
    PENDING,
    STATUS_NAMES,
    FileFormatError,
    open_file,
    reading,
    refuse_unopenable,
    storage_bytes,
)
from hpcves.run.verdict import case_data, verdict_of

log = logging.getLogger(__name__)

TAG_REQUEST = 11      # worker -> rank 0: ("ready",) | ("done", CaseResult) | ("progress", id, fraction) | ("stop",)
                      #   | with --io relay, its file writes and reads (relay.py), on this tag to keep their order
TAG_TASK = 12         # rank 0 -> worker: a queue.Task or None (no more work)
TAG_STOP = 13         # rank 0 -> worker: checkpoint the running case and report
TAG_REPLY = 14        # rank 0 -> worker: the answer to a file read (--io relay only)
PROGRESS_SECONDS = 2.0
#: CaseResult.status of a case stopped because the file system refused a write (never stored in the file)
NOT_WRITTEN = -1


@dataclass(frozen=True)
class StageProgress:
    """Where a stage stands, for a progress display: its cases that ended (and of them failed) in this
    call, those running, and the share of its cost (steps x N^2) done, running cases by how far they got."""

    ended: int
    failed: int
    running: int
    fraction: float


@dataclass(frozen=True)
class CaseResult:
    case_id: str
    status: int
    message: str
    t: float
    steps: int
    wall: float
    rank: int
    end: tuple | None = None        # (theta_tilde, psi) it ended in, when a chain's next case waits for it
    verdict: tuple | None = None    # staged studies: (verdict code, wall seconds) of an ended case (run.verdict)


@dataclass(frozen=True)
class Summary:
    """What a campaign call did, and the state of the whole file afterwards."""

    ran: tuple                      # CaseResult of every case run in this call
    counts: dict                    # status name -> number of cases in the file
    failed: tuple                   # (case_id, message) of every failed case in the file (but those that
                                    # a refinement ran again at a larger N)
    wall: float
    searches: tuple = ()            # search (refine) studies: SearchOutcome (RefineOutcome) of every search
                                    # (refinement); empty if stopped
    not_written: str = ""           # why the campaign stopped when the file system refused a write
    run_again: int = 0              # failed cases that a refinement ran again at a larger N

    @property
    def exit_status(self) -> int:
        return 2 if self.not_written else 1 if self.failed else 0


def prepare_file(study: Study, path: Path, *, resume: bool, overwrite: bool) -> tuple[str, Growth | None]:
    """Decide, on rank 0 holding the file's lock, whether to create the file or continue it; refuse
    bad files, damaged cases and what the disk has no room for. Returns ("create", None) or
    ("continue", how the study continues in the file: growth.py).

    A leftover ``.partial`` (a creation, stage or analysis cut short) is removed. With ``overwrite``
    an existing file is only replaced once its successor is complete.
    """
    if remove_partial(path):
        log.warning("%s: removed %s, left behind by an interrupted change", path, partial_path(path).name)
    if path.exists() and not overwrite:
        if not resume:
            raise FileFormatError(f"{path}: exists already; use --resume to continue it or --overwrite to "
                                  "start over")
        _drop_partial_stage(path)
        grown = check_file(study, path)
        if grown.new:
            require_space(path, file_bytes(grown.study),
                          f"a copy of the campaign file with the {len(grown.new)} cases the study adds")
        return "continue", grown
    needed = file_bytes(study)
    replaced = " (the old file is replaced only once the new one is complete)" if path.exists() else ""
    require_space(path, needed, f"the campaign file ({len(study.cases)} cases, every sample and snapshot "
                                f"preallocated){replaced}")
    return "create", None


def _drop_partial_stage(path: Path) -> None:
    """Files of hpcves before stages were added by replacement: drop a half-added stage's cases."""
    try:
        with open_file(path, "r", locking=False) as h5:
            partial = CampaignFile.has_partial_stage(h5)
    except HDF5_ERRORS:
        return                                     # check_file says what is wrong
    if partial:
        copy = copy_for_change(path, 0, "removing a half-added search stage")
        with open_file(copy, "r+") as h5:
            dropped = CampaignFile.drop_partial_stage(h5)
        publish(copy, path)
        log.warning("%s: removed %d case%s of a search stage whose adding was interrupted; the search makes "
                    "them again", path, dropped, "s" * (dropped != 1))


def check_file(study: Study, path: Path) -> Growth:
    """How ``study`` continues in the file (growth.py); refuse a file that is not this study's, or holds
    a damaged case (each one named)."""
    with open_file(path, "r", locking=False) as h5, reading(str(path)):
        campaign = CampaignFile.check(h5, str(path))
        grown = growth(study, campaign, str(path))
        damaged = campaign.damaged(grown.study)
    if damaged:
        shown = "; ".join(f"case {case_id}: {problems[0]}" for case_id, problems in damaged[:3])
        more = f"; {len(damaged) - 3} more" if len(damaged) > 3 else ""
        raise FileFormatError(f"{path}: {len(damaged)} damaged case{'s' * (len(damaged) != 1)}, not resumed "
                              f"({shown}{more}); hpcves status lists them; --overwrite starts the study over")
    return grown


def work_list(statuses: dict[str, int], study: Study, retry_failed: bool) -> list[tuple[str, bool]]:
    """(case_id, resume) for every case to run, most expensive first.

    Finished cases and those that reached the model's limit are skipped; failed ones too,
    unless ``retry_failed`` (then they start over, but those a refinement ran again at a larger N);
    a case that started continues from its last valid checkpoint, and one still pending starts without
    looking for one (it has none: its status is written before its first checkpoint; under relay the
    look costs two round trips to rank 0 a case).
    """
    todo = []
    again = run_again(study)
    for case_id, status in statuses.items():
        if status in (FINISHED, MODEL_LIMIT) or (status == FAILED and (not retry_failed or case_id in again)):
            continue
        todo.append((case_id, status not in (FAILED, PENDING)))
    todo.sort(key=lambda item: (-study.by_id(item[0]).cost, item[0]))
    return todo


def run_one(campaign: CampaignFile, task: Task, flush: Callable[[], None], rank: int,
            stop_requested: Callable[[], bool], progress: Callable[[float], None],
            analysis: AnalysisSettings, classify: bool = False) -> CaseResult:
    """Run one case to its end (or to a stop request); an exception is recorded, never raised.
    ``classify`` (a staged study): an ended case's verdict comes with the result (:func:`_verdict`)."""
    case_id = task.case_id
    store = campaign.store(case_id) if task.config is None else campaign.store(case_id, task.config)
    t0 = time.perf_counter()

    def tick(t):
        progress(t.t / t.t_end)

    try:
        out = runner.run(store, flush, resume=task.resume, progress=tick, stop_requested=stop_requested,
                         analysis=analysis, start=task.start)
        return CaseResult(case_id, out.status, out.message, out.t, out.steps, out.wall, rank,
                          out.end if task.keep_end else None,
                          _verdict(store, case_id, analysis) if classify and out.status in ENDED else None)
    except StorageError as exc:                  # the file, not the case: nothing more is written
        return CaseResult(case_id, NOT_WRITTEN, str(exc), float("nan"), 0, time.perf_counter() - t0, rank)
    except Exception as exc:                     # noqa: BLE001 -- recorded in the file, the campaign goes on
        message = f"{type(exc).__name__}: {exc}"
        try:
            store.set_status(FAILED, message, traceback.format_exc())
            flush()
        except StorageError as refused:
            return CaseResult(case_id, NOT_WRITTEN, str(refused), float("nan"), 0, time.perf_counter() - t0,
                              rank)
        return CaseResult(case_id, FAILED, message, float("nan"), 0, time.perf_counter() - t0, rank)


def _verdict(store, case_id: str, analysis: AnalysisSettings) -> tuple[int, float] | None:
    """(verdict code, wall seconds) of a case that just ended, classified by the rank that ran it -- in
    parallel, while the others run theirs, instead of by rank 0 between stages (~10 ms a tiny case;
    under --io relay rank 0 still reads its data, ~5 ms, but while the stage runs). None where it
    cannot be classified: rank 0 then classifies it between stages, as a resume does."""
    try:
        data = store.case_data() if isinstance(store, RemoteCaseStore) else case_data(store, case_id)
        verdict, wall = verdict_of(data, analysis)
    except Exception as exc:                     # noqa: BLE001 -- rank 0 tries again, and reports
        log.warning("case %s: not classified where it ran (%s: %s); rank 0 classifies it between stages",
                    case_id, type(exc).__name__, exc)
        return None
    return (verdict.code, wall) if verdict.code >= 0 else None


# ---------------------------------------------------------------------- rank 0
class Master:
    """Hands out cases, runs cases itself between scheduling turns (on few ranks), shows progress."""

    def __init__(self, run: "CampaignRun", campaign: CampaignFile, flush, todo, statuses: dict[str, int]):
        """The stage of ``run`` whose cases to run are ``todo`` (work_list), of the cases' ``statuses``."""
        study = run.study
        self.comm = run.comm
        self.relay = run.access.relay(campaign, flush)     # applies the other ranks' file writes (--io relay)
        self.size = run.size
        self.campaign, self.study, self.flush = campaign, study, flush
        self.queue = WorkQueue(todo, lambda c: study.by_id(c).cost, campaign.chain_links(), statuses,
                               lambda c: campaign.store(c).end_fields())
        self.stop_flag = run.stop_flag
        self.stop_timeout = study.stop_timeout
        self.display = run.display
        self.busy: dict[int, str] = {}           # rank -> case id
        self.fraction: dict[str, float] = {}     # case id -> fraction of its t_end reached
        self.waiting: set[int] = set()
        self._task_sends = {}                    # rank -> the send of its latest task (_send_task)
        self.results: list[CaseResult] = []
        self.stopping = False
        self.not_written = ""                    # the first write the file system refused
        self.cost_total = sum(study.by_id(c).cost for c, _ in todo)
        self.computes = computing_ranks(self.size) == self.size
        #: [(rank, request)] of the messages matched and being received, in the order they were matched
        self.incoming: list[tuple[int, object]] = []
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
            for source, message in self.received():
                active = True
                kind = message[0]
                if self.relay is not None and kind in Relay.KINDS:
                    try:
                        self.relay.handle(self.comm, source, message)
                    except StorageError as exc:      # the worker's case stops at its next step
                        self.refused(str(exc))
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
                task = None if self.stopping else self.queue.pop()
                if task is None:
                    break
                if self.relay is not None:
                    task = replace(task, config=self.relay.config(task.case_id))
                self._send_task(rank, task)
                self.waiting.discard(rank)
                self.busy[rank] = task.case_id
                self.fraction[task.case_id] = 0.0
                active = True
        if self.display is not None:
            self.display(self.progress())
        return active

    def progress(self) -> StageProgress:
        ended = [r for r in self.results if r.status in ENDED]
        return StageProgress(len(ended), sum(1 for r in ended if r.status == FAILED), len(self.busy),
                             self.cost_done() / self.cost_total if self.cost_total > 0 else 1.0)

    def received(self) -> list[tuple[int, tuple]]:
        """[(rank, message)] of the messages that have arrived whole, each rank's in the order it sent
        them. A message is matched, then received without blocking: a blocking receive of one past
        MPI's eager limit waits, spinning, until its sender's process gets a core to send the rest
        (47 % of rank 0's py-spy samples under relay at -n 16 on 2 cores), while other ranks wait
        for their replies."""
        status = self._status
        while (matched := self.comm.improbe(source=self._any_source, tag=TAG_REQUEST, status=status)) is not None:
            self.incoming.append((status.Get_source(), matched.irecv()))
        out, waiting, behind = [], [], set()
        for source, request in self.incoming:
            if source not in behind:
                done, message = request.test()
                if done:
                    out.append((source, message))
                    continue
                behind.add(source)               # its later messages wait for this one
            waiting.append((source, request))
        self.incoming = waiting
        return out

    def refused(self, why: str) -> None:
        """The file system refused a write: stop the campaign, keep the reason for the summary."""
        if not self.not_written:
            self.not_written = why
            log.warning("cannot write the campaign file: %s", why)
        self.begin_stop("the file system refused a write")

    def record(self, result: CaseResult) -> None:
        if result.status == NOT_WRITTEN:
            self.fraction.pop(result.case_id, None)
            self.refused(result.message)
            return
        self.results.append(result)
        self.fraction[result.case_id] = 1.0 if result.status in ENDED else self.fraction.get(
            result.case_id, 0.0)
        self.not_run(self.queue.ended(result.case_id, result.status, result.end))
        if result.status == FAILED:
            first = result.message.splitlines()[0] if result.message else ""
            log.warning("case %s (%s) failed on rank %d: %s", result.case_id,
                        self.study.by_id(result.case_id).label(), result.rank, first)
        elif result.status == MODEL_LIMIT:
            log.info("case %s (%s) reached the model's limit at t = %.4g: %s", result.case_id,
                     self.study.by_id(result.case_id).label(), result.t, runner.model_limit_cause(result.message))
        if result.status == INTERRUPTED and not self.stopping:
            self.begin_stop(f"rank {result.rank} was stopped")

    def not_run(self, broken) -> None:
        """Record as failed the cases of a chain that cannot start (queue.WorkQueue.ended)."""
        for case_id, why in broken:
            try:
                self.campaign.store(case_id).set_status(FAILED, why)
                self.flush()
            except StorageError as exc:
                self.refused(str(exc))
                return
            log.warning("case %s (%s): %s", case_id, self.study.by_id(case_id).label(), why)

    def begin_stop(self, why: str) -> None:
        """No new cases; every busy rank checkpoints and reports; abort if that takes too long."""
        if self.stopping:
            return
        self.stopping = True
        log.info("stopping (%s): checkpointing the running cases", why)
        if self.size > 1:
            for rank in self.busy:
                if rank != 0:
                    self.comm.send(None, dest=rank, tag=TAG_STOP)
            threading.Thread(target=self._watchdog, daemon=True).start()

    def _watchdog(self) -> None:
        time.sleep(self.stop_timeout)
        log.error("the campaign did not stop within %g s of the stop request; aborting (every case keeps "
                  "its last valid checkpoint)", self.stop_timeout)
        self.comm.Abort(3)

    def cost_done(self) -> float:
        return sum(self.study.by_id(c).cost * f for c, f in self.fraction.items())

    # -- the loop
    def run(self) -> list[CaseResult]:
        # a rank 0 that only schedules answers within 5 ms: a worker's send past MPI's eager limit waits for it
        backoff = Backoff() if self.computes else Backoff(limit=5e-3)
        self.not_run(self.queue.broken)
        while True:
            if self.service():
                backoff.reset()
            task = None if self.stopping or not self.computes else self.queue.pop()
            if task is not None:
                case_id = task.case_id
                self.fraction[case_id] = 0.0
                self.busy[0] = case_id

                def poll() -> bool:
                    self.service()
                    return self.stopping

                def progress(fraction, case_id=case_id):
                    self.fraction[case_id] = fraction

                result = run_one(self.campaign, task, self.flush, 0, poll, progress, self.study.analysis,
                                 self.study.staged)
                del self.busy[0]
                self.record(result)
                backoff.reset()
            elif not self.busy and len(self.waiting) == self.size - 1 and not self.incoming:
                break               # every other rank has asked for work: none of its messages is left unread
            else:
                backoff.sleep()
        if self.relay is not None:
            self.relay.drain()
        if self._task_sends:
            from mpi4py import MPI

            MPI.Request.Waitall(list(self._task_sends.values()))
        for rank in range(1, self.size):
            self.comm.send(None, dest=rank, tag=TAG_TASK)
        return self.results

    def _send_task(self, rank: int, task: Task) -> None:
        """Send ``task`` without waiting for ``rank`` to take it: a task with its config (relay) passes
        MPI's eager limit (4 KiB on shared memory), and a blocking send of it spun rank 0 until the
        worker woke from its backoff to receive it (rank 0 used 24x a worker's CPU). The rank asks
        again only after it took the one before, which is therefore complete."""
        previous = self._task_sends.pop(rank, None)
        if previous is not None:
            previous.Wait()
        self._task_sends[rank] = self.comm.isend(task, dest=rank, tag=TAG_TASK)


# ---------------------------------------------------------------------- other ranks
def worker_loop(comm, campaign: CampaignFile, flush, stop_flag, analysis: AnalysisSettings,
                classify: bool = False) -> None:
    """Ask rank 0 for cases and run them until told there are no more (``classify``: run_one's)."""
    rank = comm.Get_rank()
    comm.send(("ready",), dest=0, tag=TAG_REQUEST)
    told_stop = False
    backoff = Backoff()
    while True:
        if comm.Iprobe(source=0, tag=TAG_TASK):
            task = comm.recv(source=0, tag=TAG_TASK)
            if task is None:
                break
            case_id = task.case_id
            last = [0.0]

            def stop_requested() -> bool:
                return stop_flag() or comm.Iprobe(source=0, tag=TAG_STOP)

            def progress(fraction, case_id=case_id):
                now = time.monotonic()
                if now - last[0] >= PROGRESS_SECONDS:
                    last[0] = now
                    comm.send(("progress", case_id, fraction), dest=0, tag=TAG_REQUEST)

            result = run_one(campaign, task, flush, rank, stop_requested, progress, analysis, classify)
            if isinstance(campaign, RemoteCampaign):
                campaign.send_pending()             # rank 0 takes the "done" after every write of the case
            comm.send(("done", result), dest=0, tag=TAG_REQUEST)
            backoff.reset()
        else:
            if stop_flag() and not told_stop:       # signalled while idle: tell rank 0
                told_stop = True
                comm.send(("stop",), dest=0, tag=TAG_REQUEST)
            backoff.sleep()
    while comm.Iprobe(source=0, tag=TAG_STOP):      # a stop that crossed our last report
        comm.recv(source=0, tag=TAG_STOP)
    if isinstance(campaign, RemoteCampaign):
        campaign.wait_sent()


# ---------------------------------------------------------------------- the whole job
@dataclass
class CampaignRun:
    """One call of :func:`run_campaign` on one rank: what its parts share. ``study`` grows as a staged
    study adds its cases (on rank 0, which keeps the cases)."""

    study: Study
    path: Path
    comm: object                          # None: this process alone
    access: FileAccess
    retry_failed: bool
    stop_flag: Callable[[], bool]
    display: Callable | None
    announce: Callable[[str, int | None, tuple[int, int]], None]
    on_stage: Callable[[list], None]
    start: float = field(default_factory=time.perf_counter)

    @property
    def size(self) -> int:
        return 1 if self.comm is None else self.comm.Get_size()

    @property
    def rank(self) -> int:
        return 0 if self.comm is None else self.comm.Get_rank()


def run_campaign(study: Study, path: Path, comm=None, *, resume: bool = False, retry_failed: bool = False,
                 overwrite: bool = False, io: str = "auto", stop_flag: Callable[[], bool] = lambda: False,
                 display=None,
                 announce: Callable[[str, int | None, tuple[int, int]], None] = lambda text, total, ended: None,
                 on_stage: Callable[[list], None] = lambda outcomes: None) -> Summary:
    """Run (or continue) a study into ``path`` on every rank of ``comm`` (None: this process alone).

    ``io`` (several ranks only): "mpio" -- every rank opens the file with
    h5py's MPI driver; "relay" -- only rank 0 opens it and applies the other
    ranks' writes (relay.py); "auto" -- mpio where h5py has MPI, else relay.

    A search or refine study (``study.staged``) runs in stages
    (search_stages.py, refine_stages.py): after each, rank 0 classifies
    the finished cases, the searches (refinements) choose their next shear
    rates (points), and the file is replaced by a copy holding those cases
    before the next stage runs them. Rank 0 calls ``on_stage(outcomes)`` with
    the state of every search (refinement) after each stage.

    Rank 0 calls ``announce(text, None, (0, 0))`` with the campaign's
    first line, ``announce(text, n_cases, (n_ended, n_failed))`` once the work
    of a stage is known (the cases that ended before it, and how many of
    those failed), and ``display(progress)`` (a :class:`StageProgress`) at every scheduling turn.

    Collective: every rank calls it with the same study. Bad input raises
    the same hpcves error (errors.py) on every rank (the message is rank 0's).
    """
    size = 1 if comm is None else comm.Get_size()
    rank = 0 if comm is None else comm.Get_rank()
    start = time.perf_counter()
    access = file_access(choose_io(io, size), comm, TAG_REQUEST, TAG_REPLY)
    given, path = Path(path), real_path(path)         # every change goes to the file itself, not a symlink
    lock = CampaignLock(given)
    verdict = None
    if rank == 0:
        try:
            refuse_unopenable(given, "r+" if resume else "a")      # before a lock file is made beside it
            lock.acquire()
            verdict = ("ok", prepare_file(study, path, resume=resume, overwrite=overwrite))
        except HpcvesError as exc:           # every rank raises the same class, with rank 0's message
            lock.release()
            verdict = ("error", type(exc), str(exc).replace(str(path), str(given)))
    if size > 1:
        verdict = bcast(comm, verdict)
    if verdict[0] == "error":
        raise verdict[1](verdict[2])
    mode, grown = verdict[1]
    study = grown.study if grown is not None else study
    try:
        if rank > 0:
            refused = ""
            try:
                lock.join(rank)
            except LockError as exc:
                refused = str(exc)
        if size > 1:
            problems = [p for p in comm.allgather(refused if rank > 0 else "") if p]
            if problems:
                raise LockError(problems[0])
        if grown is not None and grown.grows:
            if rank == 0:
                announce(f"{path}: the study grew: {'; '.join(grown.changes)}; its computed cases are kept",
                         None, (0, 0))
            refused = _grow(path, comm, grown)
            if refused:
                raise StorageError(refused)
        run = CampaignRun(study, path, comm, access, retry_failed, stop_flag, display, announce, on_stage, start)
        return _run_locked(run, mode)
    finally:
        lock.release()


def _run_locked(run: CampaignRun, mode: str) -> Summary:
    """The campaign once the file is this study's and locked: created or continued, stage after stage."""
    study, path, comm, access, rank = run.study, run.path, run.comm, run.access, run.rank
    if mode == "create":
        if rank == 0:
            run.announce(f"creating {path} ({len(study.cases)} cases, "
                         f"{size_text(sum(storage_bytes(c.case) for c in study.cases))})", None, (0, 0))
        _create(study, path, comm)
    h5, campaign, flush = access.open(path)
    not_written = ""
    try:
        results, outcomes = [], []
        driver = None
        if rank == 0 and study.staged:
            driver = (SearchDriver if study.search else RefineDriver)(study)
            if mode == "continue":
                run.study = driver.cases_from_file(study, campaign)
        stage, ended = 0, None
        while True:
            ran, stopped, refused = _run_stage(run, campaign, flush, mode, stage, ended)
            ended = time.perf_counter()
            results += ran
            not_written = not_written or refused
            if not run.study.staged:
                break
            access.sync(h5)                  # rank 0 is about to read the cases the others wrote
            plan, failure = ("stop",), None
            if rank == 0 and not stopped:
                try:
                    driver.ran(ran)
                    outcomes, new = driver.next_stage(run.study, campaign)
                    campaign.store_verdicts(driver.fresh)     # classified once: a resume or status reads them
                    driver.fresh.clear()
                    faults.point("verdicts-stored")
                    run.on_stage(outcomes)
                    plan = ("add", new) if new else ("done",)
                except Exception as exc:      # told to every rank, which would wait for the plan for ever
                    failure, own = exc, isinstance(exc, HpcvesError)
                    plan = ("error", type(exc) if own else RuntimeError, str(exc) if own else
                            f"{type(exc).__name__}: {exc}")
            if run.size > 1:
                plan = bcast(comm, plan)
            if failure is not None:
                raise failure
            if plan[0] == "error":
                raise plan[1](plan[2])
            if plan[0] != "add":
                break
            if rank == 0:
                run.study = run.study.with_cases(plan[1])
            if h5 is not None:
                h5.close()
                h5 = None
            refused = _add_stage(path, comm, plan[1], stage + 1, run.study.source)
            if refused:
                not_written = refused
                if rank == 0:
                    log.warning("cannot add the next stage's cases: %s", refused)
                h5, campaign, flush = access.open(path)
                break
            h5, campaign, flush = access.open(path)
            stage += 1
        summary = None
        if rank == 0:
            counts = {name: 0 for name in STATUS_NAMES.values()}
            failed, again = [], run_again(run.study)
            for row in campaign.table():
                counts[row["status"]] = counts.get(row["status"], 0) + 1
                if row["status"] == "failed" and row["case"] not in again:
                    failed.append((row["case"], row["message"]))
            summary = Summary(tuple(results), counts, tuple(failed), time.perf_counter() - run.start,
                              tuple(outcomes), not_written, len(again))
    finally:
        if h5 is not None:
            try:
                h5.close()
            except HDF5_ERRORS:
                pass                               # a refused write was reported already
    if run.size > 1:
        summary = comm.bcast(summary, root=0)
    return summary


def _run_stage(run: CampaignRun, campaign, flush, mode: str, stage: int,
               ended: float | None = None) -> tuple[list[CaseResult], bool, str]:
    """Run every unfinished case of the file on every rank: (results, whether it was stopped, why the
    file system refused a write or "") on rank 0; ``ended``: when the stage before ended (perf_counter),
    to say how long rank 0 took between the two. Failed cases run again with ``run.retry_failed``, in the
    first stage only."""
    study, size = run.study, run.size
    results, stopped, refused = [], False, ""
    if run.rank == 0:
        statuses = campaign.statuses()
        todo = work_list(statuses, study, run.retry_failed and stage == 0)
        to_run = {case_id for case_id, _ in todo}
        before = [s for case_id, s in statuses.items() if case_id not in to_run]
        ended_before = (len(before), sum(1 for s in before if s == FAILED))
        if stage == 0:
            run.announce(_announcement(study, run.path, statuses, size, mode, run.access), None, (0, 0))
        if todo or not study.staged:
            line = _stage_line(study, statuses, todo, stage, size)
            if ended is not None:
                line += f"; {time.perf_counter() - ended:.1f} s between stages"
            run.announce(line, len(statuses), ended_before)
        master = Master(run, campaign, flush, todo, statuses)
        results = master.run()
        stopped, refused = master.stopping, master.not_written
    else:
        worker_loop(run.comm, campaign, flush, run.stop_flag, study.analysis, study.staged)
    if size > 1:
        wait(run.comm.Ibarrier())     # everyone is done writing before the collective close (or the next stage)
    return results, stopped, refused


def file_bytes(study: Study) -> int:
    """The size of a new campaign file of ``study``'s known cases: every sample and snapshot preallocated."""
    return METADATA_BYTES_PER_FILE + sum(storage_bytes(c.case) for c in study.cases)


def _create(study: Study, path: Path, comm) -> None:
    """Lay out the whole file under ``<path>.partial`` (rank 0 alone: :func:`_change`), then rename it to ``path``.

    Rank 0 first reserves the space on disk (atomic.new_partial), so that a full disk refuses
    here, before HDF5 writes anything.
    """
    def reserve():
        new_partial(path, file_bytes(study),
                    f"the campaign file ({len(study.cases)} cases, every sample and snapshot preallocated)")

    failure = _change(path, comm, reserve, lambda h5: CampaignFile.create(h5, study), "cannot create it",
                      "nothing was written")
    if failure:
        raise StorageError(failure)


def _add_stage(path: Path, comm, cases, stage: int, source: str) -> str:
    """Add a search (refine) stage's cases to a copy of the file that then replaces it, with the
    campaign file's text ``source`` (a refinement's budget may have been raised); "" or why it could not be."""
    def reserve():
        copy_for_change(path, sum(storage_bytes(c.case) for c in cases), f"adding stage {stage}'s {len(cases)} cases")

    return _change(path, comm, reserve, lambda h5: CampaignFile(h5).add_cases(cases, source),
                   f"cannot add stage {stage}'s cases", "the file is unchanged")


def _grow(path: Path, comm, grown: Growth) -> str:
    """Make the file the grown study's (growth.py): its fingerprint and text, a search's list of searches,
    and a grid's new cases laid out, in a copy that replaces the file; "" or why it could not be."""
    def reserve():
        copy_for_change(path, sum(storage_bytes(c.case) for c in grown.new),
                        f"adding the {len(grown.new)} cases the study grew by")

    return _change(path, comm, reserve, lambda h5: CampaignFile(h5).grow(grown.study, grown.new),
                   "cannot grow it to the study", "the file is unchanged")


def _change(path: Path, comm, reserve, change, cannot: str, after: str) -> str:
    """A change of the file's structure, made whole or not at all: rank 0 reserves the space of
    ``<path>.partial`` (``reserve``: a new file or a copy), applies ``change(h5)`` to it and renames
    it to ``path``. "" or why not ("<path>: <cannot> (<reason>); <after>"), the same on every rank.

    Rank 0 does it alone, with serial HDF5, in every I/O mode: nobody else has the partial file open,
    and under mpio every object created is a collective operation that all ranks wait on (laying out
    500 tiny cases took 159 s on 8 ranks against 8 s in one process); the ranks open the finished
    file together afterwards."""
    rank = 0 if comm is None else comm.Get_rank()
    size = 1 if comm is None else comm.Get_size()
    refused = ""
    if rank == 0:
        try:
            reserve()
        except StorageError as exc:
            refused = str(exc)
    if size > 1:
        refused = bcast(comm, refused)
    if refused:
        return refused
    partial = partial_path(path)
    if rank == 0:
        try:
            h5 = open_file(partial, "r+")
            try:
                change(h5)
            finally:
                h5.close()                        # the structure is on disk
        except (*HDF5_ERRORS, HpcvesError) as exc:
            remove_partial(path)
            reason = str(exc).strip().splitlines()[0] if str(exc).strip() else str(exc)
            refused = f"{path}: {cannot} ({reason}); {after}"
        if rank == 0 and not refused:
            try:
                publish(partial, path)
            except OSError as exc:
                remove_partial(path)
                refused = f"{path}: cannot rename {partial.name} to it ({exc.strerror}); {after}"
    if size > 1:
        refused = bcast(comm, refused)
    return refused


def _announcement(study, path, statuses, size, mode, access: FileAccess) -> str:
    """The first line of a campaign: what, where, on how many ranks."""
    verb = "new file" if mode == "create" else "continuing"
    if study.refine:
        x, y = study.refine_settings.x, study.refine_settings.y
        n = len(study.refinements)
        what = (f"{n} refinement{'s' * (n != 1)} of the regime boundaries over {x.key} x {y.key} from a "
                f"{len(x.values)} x {len(y.values)} grid (at most {study.refine.max_cases} cases each), "
                f"{len(statuses)} cases so far")
    elif study.search is None:
        what = f"{len(study.cases)} cases"
    else:
        n = len(study.searches)
        kind = "critical-shear" if study.search.along == "shear_rate" else "critical-lambda"
        what = (f"{n} {kind} search{'es' * (n != 1)} over {study.search.symbol} in [{study.search.low:g}, "
                f"{study.search.high:g}] to {study.search.rel_tol:g} (at most {study.search.max_cases} cases each), "
                f"{len(statuses)} cases so far")
    return f"campaign {study.name!r} -> {path} ({verb}): {what}; {size} rank{'s' * (size > 1)}, {access.description}"


def _stage_line(study, statuses, todo, stage, size: int = 1) -> str:
    """What a stage runs: cases to run, resumed, finished and failed before -- and, where ``size`` ranks
    (rank 0 among them: it runs cases too) outnumber its cases, how many of them wait idle."""
    finished = sum(1 for s in statuses.values() if s == FINISHED)
    failed = sum(1 for s in statuses.values() if s == FAILED)
    resumed = sum(1 for case_id, resume in todo if resume)
    parts = [f"{len(todo)} to run"]
    if resumed:
        parts.append(f"{resumed} from a checkpoint")
    if finished:
        parts.append(f"{finished} finished before")
    if failed:
        parts.append(f"{failed} failed before" + ("" if any(not r for _, r in todo) else
                                                  " (--retry-failed reruns them)"))
    limited = sum(1 for s in statuses.values() if s == MODEL_LIMIT)
    if limited:
        parts.append(f"{limited} at the model's limit before")
    if study.staged and stage > 0:
        groups = len({study.by_id(case_id).search for case_id, _ in todo})
        kind = "search" if study.search else "refinement"
        parts[0] = f"stage {stage}: {len(todo)} new case{'s' * (len(todo) != 1)} for {groups} " \
                   f"{kind}{('es' if study.search else 's') * (groups != 1)}"
    line = ", ".join(parts)
    if 0 < len(todo) < size:
        line += (f"; {size - len(todo)} of the {size} ranks idle: more ranks than cases"
                 + (" in this stage" if study.staged else " (fewer ranks do the same in the same time)"))
    return line
