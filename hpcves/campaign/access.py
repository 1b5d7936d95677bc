"""How the ranks of a campaign reach its HDF5 file: one object per mode, the same methods.

* :class:`SerialAccess` -- one process; the default HDF5 driver.
* :class:`MpioAccess` -- several ranks and an h5py built with MPI: every rank
  opens the file with the ``mpio`` driver. Changes of the structure (creating
  the file, adding a stage's cases) are collective; afterwards each case is
  written only by the rank that runs it (independent raw-data writes to
  preallocated datasets, which reach the file in program order, so a flush has
  nothing to do: File.flush would be collective). Rank 0 reads what the others
  wrote only after they sync (a collective flush and a barrier).
* :class:`RelayAccess` -- several ranks without MPI in h5py (or ``--io relay``):
  rank 0 alone opens the file; the other ranks get a RemoteCampaign whose
  writes rank 0 applies in order (relay.py).

The campaign (driver.py, stages.py, scheduler.py) asks every mode the same things: open the file, make a
flush, run a change of the structure, say whether this rank takes part in it,
sync before rank 0 reads, and what rank 0 needs to relay the others' writes.
"""
from __future__ import annotations

from pathlib import Path

from hpcves.campaign import IO_MODES  # the choices of --io: "auto" is mpio where h5py has MPI, else relay
from hpcves.campaign.file import CampaignFile
from hpcves.campaign.polling import bcast, wait_until
from hpcves.campaign.relay import Relay, RemoteCampaign
from hpcves.errors import HpcvesError
from hpcves.model.params import ConfigError
from hpcves.run.store import FileFormatError, open_file, safe_flush


class FileAccess:
    """One process alone (also the base of the other modes)."""

    name, description = "serial", "serial HDF5"

    def __init__(self, comm=None):
        self.comm = comm
        self.rank = 0 if comm is None else comm.Get_rank()

    def open_h5(self, path: Path, mode: str):
        return open_file(path, mode)

    def open(self, path: Path):
        """(h5 or None, campaign, flush) on this rank for the existing file at ``path``."""
        h5 = None
        try:
            h5 = self.open_h5(path, "r+")
            campaign = CampaignFile(h5)
        except HpcvesError as exc:
            if h5 is not None:
                h5.close()
            self._opened(str(exc))
            raise
        self._opened(None)
        return h5, campaign, self.flush_for(h5)

    def _opened(self, error: str | None) -> None:
        """Tell the ranks that do not open the file whether rank 0 could (relay)."""

    def flush_for(self, h5):
        """What makes this rank's writes durable."""
        return safe_flush(h5)

    def sync(self, h5) -> None:
        """Before rank 0 reads the cases the other ranks wrote."""

    def relay(self, campaign, flush) -> Relay | None:
        """Rank 0's handler of the other ranks' file writes, where they send them."""
        return None


SerialAccess = FileAccess


class MpioAccess(FileAccess):
    """Every rank opens the file with h5py's MPI driver."""

    name, description = "mpio", "parallel HDF5"

    def open_h5(self, path: Path, mode: str):
        return open_file(path, mode, driver="mpio", comm=self.comm)

    def flush_for(self, h5):
        return _nothing          # raw writes reach the file at once, in program order

    def sync(self, h5) -> None:
        # MPI-IO makes the others' writes visible after a sync by the writers (H5Fflush,
        # collective) and a barrier
        h5.flush()
        self.comm.Barrier()


class RelayAccess(FileAccess):
    """Rank 0 opens the file and applies the other ranks' writes."""

    name, description = "relay", "HDF5 through rank 0"

    def __init__(self, comm, request_tag: int, reply_tag: int):
        super().__init__(comm)
        self.request_tag, self.reply_tag = request_tag, reply_tag

    def open(self, path: Path):
        if self.rank > 0:
            refused = bcast(self.comm, None)
            if refused is not None:
                raise FileFormatError(refused)
            remote = RemoteCampaign(self.comm, self.request_tag, self.reply_tag, wait_until)
            return None, remote, remote.flush
        return super().open(path)

    def _opened(self, error: str | None) -> None:
        bcast(self.comm, error)

    def relay(self, campaign, flush) -> Relay:
        return Relay(campaign, flush, self.reply_tag)


def _nothing() -> None:
    pass


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


def file_access(io: str, comm, request_tag: int, reply_tag: int) -> FileAccess:
    """The FileAccess of mode ``io`` (choose_io's answer) on this rank of ``comm``."""
    if io == "mpio":
        return MpioAccess(comm)
    if io == "relay":
        return RelayAccess(comm, request_tag, reply_tag)
    return FileAccess(comm)
