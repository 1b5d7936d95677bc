"""The work of a stage on every rank: rank 0 schedules (and computes, on few ranks), the others compute.

Scheduling (:class:`Master`, rank 0). Cases go out most expensive first
(cost = steps x N^2) to whichever rank asks. On up to 4 ranks (queue.RANK0_COMPUTES_UP_TO)
rank 0 runs cases itself: its run loop polls the message queue once per time step
(``MPI.Iprobe``, ~1 us) and answers requests there, so with ``mpirun -n 2`` on two
cores both cores compute. On more ranks it only schedules (and, under relay, writes
for everyone): a time step between its answers holds up every other rank, and the
answers of a whole job add up to more than a worker's computing (under relay at -n 8,
rank 0 running cases too used 7x a worker's CPU and set the pace). Nobody busy-waits:
a rank with nothing to compute polls with a sleep that backs off from 1 ms to 50 ms (as
mpi4py.futures does), and the final synchronisation is a non-blocking barrier polled the
same way.

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
"""
from __future__ import annotations

import logging
import threading
import time
import traceback
from dataclasses import dataclass, replace
from typing import Callable

from hpcves.analysis.regimes import AnalysisSettings
from hpcves.campaign.file import CampaignFile
from hpcves.campaign.polling import Backoff
from hpcves.campaign.queue import Task, WorkQueue, computing_ranks
from hpcves.campaign.relay import Relay, RemoteCampaign, RemoteCaseStore
from hpcves.campaign.state import CampaignRun
from hpcves.files.atomic import StorageError
from hpcves.run import runner
from hpcves.run.store import ENDED, FAILED, INTERRUPTED, MODEL_LIMIT
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

    def __init__(self, run: CampaignRun, campaign: CampaignFile, flush, todo, statuses: dict[str, int]):
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
