"""Campaign file access through rank 0, for when the ranks cannot share the file.

With an h5py built without MPI (or ``--io relay``, for file systems where
MPI-IO misbehaves) only rank 0 opens the campaign file. The other ranks run
their cases against a :class:`RemoteCaseStore`, which has the interface of
:class:`~hpcves.run.store.CaseStore` but forwards every write to rank 0 as a
message; rank 0's :class:`Relay` applies them to the real store.

Order is what makes this safe. The writes travel on the same tag as the
worker's scheduling messages, and MPI never reorders messages between two
ranks on one tag, so rank 0 applies each worker's writes in the order they
were made, and its "done" after all of them. A worker gathers its writes and
sends them in one message when it flushes, reads, writes a checkpoint or
reports its case (~10 messages a tiny case instead of ~25); a write the worker
has not sent yet is one the file had not made durable either. The file
therefore always holds a prefix of each case's writes -- exactly what the
checkpoint protocol (invalidate the slot, write it, validate it) needs to
survive a kill at any moment, as it does under ``mpio``. Reads are a round
trip; a run makes a few when it starts (its case's text, progress, newest
checkpoint and, when it resumes or runs until decided, its series so far) and
none after.
"""
from __future__ import annotations

from typing import Callable

from hpcves.campaign.file import CampaignFile
from hpcves.run.store import RUNNING, stored_case
from hpcves.run.verdict import case_data

#: CaseStore methods a worker may have applied on rank 0, and attributes it may read there
WRITES = frozenset({"set_status", "set_progress", "append_samples", "append_snapshots", "truncate",
                    "write_checkpoint", "set_decision"})
READS = frozenset({"config", "status", "progress", "read_checkpoint", "passed_over", "newest_checkpoint_slot",
                   "timeseries", "case_data"})


class Relay:
    """Rank 0's side: apply the writes and answer the reads of the other ranks."""

    KINDS = ("writes", "read")

    def __init__(self, campaign: CampaignFile, flush: Callable[[], None], reply_tag: int):
        self.campaign, self.flush, self.reply_tag = campaign, flush, reply_tag
        self._stores = {}
        #: {rank: its last reply}, sent without waiting (a blocking send of a reply past MPI's eager
        #: limit -- a case, a checkpoint -- spun rank 0 until the worker's next poll took it: at -n 8
        #: under relay, rank 0 used 12 times a worker's CPU). A rank asks again only after it has
        #: received its reply, so the one before is complete by then (testing every reply on every read
        #: took a tenth of rank 0's time at -n 16)
        self._replies = {}

    def config(self, case_id: str) -> str:
        """The stored TOML text of a case about to be handed out (sent with its task)."""
        return self._store(case_id).config

    def _store(self, case_id: str):
        if case_id not in self._stores:
            self._stores[case_id] = self.campaign.store(case_id)
        return self._stores[case_id]

    def handle(self, comm, source: int, message: tuple) -> None:
        kind = message[0]
        if kind == "writes":
            _, writes, flush = message
            for case_id, name, args in writes:
                self._write(source, case_id, name, args)
            if flush:
                self.flush()
        elif kind == "read":
            _, case_id, name = message
            try:
                if name not in READS:
                    raise ValueError(f"unknown read {name!r}")
                if name == "case_data":           # what the worker classifies its ended case from
                    reply = ("ok", case_data(self._store(case_id), case_id))
                else:
                    value = getattr(self._store(case_id), name)
                    reply = ("ok", value() if callable(value) else value)
            except Exception as exc:            # noqa: BLE001 -- raised again on the asking rank
                reply = ("error", exc)
            previous = self._replies.pop(source, None)
            if previous is not None:
                previous.Wait()
            self._replies[source] = comm.isend(reply, dest=source, tag=self.reply_tag)
        else:
            raise ValueError(f"rank {source} sent an unknown file request {kind!r}")

    def _write(self, source: int, case_id: str, name: str, args: tuple) -> None:
        if name not in WRITES:
            raise ValueError(f"rank {source} asked for an unknown write {name!r}")
        store = self._store(case_id)
        if name == "write_checkpoint":
            store.write_checkpoint(*args, self.flush)
        else:
            getattr(store, name)(*args)
        if name == "set_status" and args[0] != RUNNING:
            # the run is over: its datasets are closed (every flush visits each open dataset)
            del self._stores[case_id]

    def drain(self) -> None:
        """Wait until every reply is taken (each asking rank waits for its own before it goes on)."""
        from mpi4py import MPI

        MPI.Request.Waitall(list(self._replies.values()))
        self._replies = {}


class RemoteCaseStore:
    """A worker's view of one case: the run's interface to it (store.CaseRecord), served by rank 0."""

    def __init__(self, campaign: "RemoteCampaign", case_id: str, config: str | None = None):
        self.campaign, self.comm, self.case_id = campaign, campaign.comm, case_id
        self._request_tag, self._reply_tag = campaign.tags
        self._wait = campaign.wait
        #: the case's stored text, where rank 0 sent it with the task
        self._config = config

    def _write(self, name: str, *args) -> None:
        self.campaign.pending.append((self.case_id, name, args))

    def _read(self, name: str):
        self.campaign.send_pending()
        self.campaign.post(("read", self.case_id, name))
        self._wait(lambda: self.comm.Iprobe(source=0, tag=self._reply_tag))
        verdict, value = self.comm.recv(source=0, tag=self._reply_tag)
        if verdict == "error":
            raise value
        return value

    # reads
    @property
    def case(self):
        """Parsed here: rank 0 sends the text (parsing costs ~ms, and rank 0 serves every rank)."""
        if self._config is None:
            self._config = self._read("config")
        return stored_case(self._config, f"/cases/{self.case_id}")

    status = property(lambda self: self._read("status"))
    progress = property(lambda self: self._read("progress"))

    def read_checkpoint(self):
        return self._read("read_checkpoint")

    def passed_over(self):
        return self._read("passed_over")

    def newest_checkpoint_slot(self):
        return self._read("newest_checkpoint_slot")

    def timeseries(self):
        return self._read("timeseries")

    def case_data(self):
        """What run.verdict classifies an ended case from, read on rank 0 (run.verdict.case_data)."""
        return self._read("case_data")

    # writes
    def set_status(self, status, message=None, traceback=None):
        self._write("set_status", status, message, traceback)

    def set_progress(self, t, t_end, wall, steps_per_second):
        self._write("set_progress", t, t_end, wall, steps_per_second)

    def append_samples(self, rows):
        if rows:
            self._write("append_samples", list(rows))

    def append_snapshots(self, snaps):
        if snaps:
            self._write("append_snapshots", list(snaps))

    def truncate(self, n_samples, n_snapshots):
        self._write("truncate", n_samples, n_snapshots)

    def set_decision(self, code, t, step):
        self._write("set_decision", code, t, step)

    def write_checkpoint(self, state, flush):
        """Rank 0 writes it with its own flushes between the phases; ``flush`` is not needed here."""
        self._write("write_checkpoint", state)
        self.campaign.send_pending()


class RemoteCampaign:
    """What a worker sees of the campaign file: ``store(case_id)`` and a ``flush``; the writes of its
    stores wait in ``pending`` until they are sent together (:meth:`send_pending`)."""

    def __init__(self, comm, request_tag: int, reply_tag: int, wait: Callable):
        self.comm, self.tags, self.wait = comm, (request_tag, reply_tag), wait
        #: [(case id, CaseStore method, arguments)] not sent yet, in the order they were made
        self.pending = []
        #: sends on their way (MPI keeps them in order): a blocking send past the eager limit spins
        #: until rank 0 takes it
        self._sent = []

    def store(self, case_id: str, config: str | None = None) -> RemoteCaseStore:
        """Case ``case_id``; ``config``: its stored text, where it came with the task."""
        return RemoteCaseStore(self, case_id, config)

    def send_pending(self, flush: bool = False) -> None:
        """Send the pending writes to rank 0 as one message (and ask it to flush the file after them)."""
        if self.pending or flush:
            writes, self.pending = self.pending, []
            self.post(("writes", writes, flush))

    def post(self, message: tuple) -> None:
        """Send ``message`` to rank 0 without waiting for it to be taken."""
        self._sent = [request for request in self._sent if not request.Test()]
        self._sent.append(self.comm.isend(message, dest=0, tag=self.tags[0]))

    def wait_sent(self) -> None:
        """Wait until rank 0 has taken every message sent (before this rank leaves the campaign)."""
        self.wait(lambda: all(request.Test() for request in self._sent))
        self._sent = []

    def flush(self) -> None:
        self.send_pending(flush=True)
