"""The cases rank 0 still has to hand out, and which of them may start now.

Most work first: a case's priority is its cost (steps x N^2), plus -- in a chain
study -- the cost of every case after it in its chain, so the longest chains
start first and the ranks stay busy with the others meanwhile (list scheduling
by the critical path). A chain's case is ready once the case before it has
finished; it then starts from that case's end state, which the queue holds
(handed in when the case finishes in this call, read from the file for cases
finished before). When a case before others ends otherwise (failed, at the
model's limit), the rest of its chain cannot start: :meth:`WorkQueue.ended`
returns them, for rank 0 to record as failed, saying why.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from hpcves.run.store import FAILED, FINISHED, MODEL_LIMIT, STATUS_NAMES

#: the most ranks on which rank 0 runs cases itself between scheduling turns (scheduler.Master); on more it
#: only schedules (and relays)
RANK0_COMPUTES_UP_TO = 4


def computing_ranks(ranks: int) -> int:
    """How many of a job's ``ranks`` run cases: all of them on up to RANK0_COMPUTES_UP_TO, else all but rank 0."""
    return ranks if ranks <= RANK0_COMPUTES_UP_TO else ranks - 1


def ranks_for(computing: int) -> int:
    """The fewest ranks of a job in which ``computing`` ranks run cases."""
    return computing if computing <= RANK0_COMPUTES_UP_TO else computing + 1


@dataclass(frozen=True)
class Task:
    """One case to run: continue from its checkpoint (``resume``), from which state (``start``), and
    whether its end state is wanted back (``keep_end``: a case of the chain waits for it); ``config``:
    the case's stored TOML text, sent with it under ``--io relay`` (rank 0 holds it; asking for it was a
    round trip a case)."""

    case_id: str
    resume: bool
    start: tuple | None = None
    keep_end: bool = False
    config: str | None = None


class WorkQueue:
    """Cases to run (``todo``: (case id, resume)), ordered by priority, ready when their chain allows."""

    def __init__(self, todo, cost: Callable[[str], float], links: dict[str, str], statuses: dict[str, int],
                 read_end: Callable[[str], tuple]):
        """``links``: {case: the case it starts from}; ``statuses``: of every case in the file;
        ``read_end(case)``: a finished case's end fields from the file."""
        self.resume = dict(todo)
        self.links = {c: p for c, p in links.items() if c in self.resume}
        self.next_of = {p: c for c, p in self.links.items()}
        self.ends: dict[str, tuple] = {}
        self.broken: list[tuple[str, str]] = []        # (case, why) that cannot run: recorded by rank 0
        priority = {}
        for case_id in self.resume:
            total, c = 0.0, case_id
            while c is not None:
                total += cost(c)
                c = self.next_of.get(c) if c in self.resume else None
            priority[case_id] = total
        self.order = sorted(self.resume, key=lambda c: (-priority[c], c))
        for case_id, before in self.links.items():
            if before in self.resume:
                continue
            status = statuses.get(before)
            if status == FINISHED:
                self.ends[before] = read_end(before)
            else:
                self._break(before, STATUS_NAMES.get(status, str(status)))

    def __len__(self) -> int:
        return len(self.order)

    def ready(self, case_id: str) -> bool:
        before = self.links.get(case_id)
        return before is None or before in self.ends

    def pop(self) -> Task | None:
        """The ready case of highest priority, taken off the queue (None if none is ready)."""
        for i, case_id in enumerate(self.order):
            if self.ready(case_id):
                del self.order[i]
                before = self.links.get(case_id)
                return Task(case_id, self.resume[case_id], self.ends.get(before) if before else None,
                            case_id in self.next_of)
        return None

    def ended(self, case_id: str, status: int, end: tuple | None) -> list[tuple[str, str]]:
        """Case ``case_id`` ended with ``status`` (and, finished, the ``end`` fields): its chain goes on,
        or the cases after it that can no longer start, (case, why), are returned (and dropped)."""
        if case_id not in self.next_of:
            return []
        if status == FINISHED:
            self.ends[case_id] = end
            return []
        if status not in (FAILED, MODEL_LIMIT):       # interrupted: it resumes, and its chain with it
            return []
        before = len(self.broken)
        self._break(case_id, STATUS_NAMES.get(status, str(status)))
        return self.broken[before:]

    def _break(self, case_id: str, how: str) -> None:
        """Drop every case after ``case_id`` in its chain, which ended ``how``."""
        c = self.next_of.get(case_id)
        while c is not None and c in self.order:
            self.order.remove(c)
            self.broken.append((c, f"not run: it starts from the end of case {case_id}, which ended {how} "
                                   "(--retry-failed runs the chain on from there)"))
            c = self.next_of.get(c)
