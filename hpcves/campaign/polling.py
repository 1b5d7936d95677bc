"""Waiting on MPI without spinning: a backoff sleep, polled requests, a broadcast after a quiet barrier.

MPI's own waits keep a core busy; on a laptop with ``mpirun -n 2`` that core is
the one rank 0 computes on. These helpers sleep 1 ms, doubling to 50 ms, between
polls (as mpi4py.futures does).
"""
from __future__ import annotations

import time
from typing import Callable


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


def bcast(comm, value, root: int = 0):
    """``comm.bcast`` without spinning: a non-blocking barrier polled with a backoff first, so that
    ranks waiting for rank 0's serial work (reading, copying, classifying) leave their cores alone."""
    wait(comm.Ibarrier())
    return comm.bcast(value, root=root)
