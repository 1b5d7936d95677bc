"""Changes of a campaign file's structure -- its creation, a stage's cases, a grown study -- made
whole or not at all: rank 0 alone, with serial HDF5, lays them out in ``<file>.partial`` (a new file
or a copy, its space reserved first) and renames it to the file (files/atomic.py)."""
from __future__ import annotations

from pathlib import Path

from hpcves.campaign.file import CampaignFile
from hpcves.campaign.growth import Growth
from hpcves.campaign.polling import bcast
from hpcves.campaign.study import Study
from hpcves.errors import HpcvesError
from hpcves.files.atomic import (
    METADATA_BYTES_PER_FILE,
    StorageError,
    copy_for_change,
    new_partial,
    partial_path,
    publish,
    remove_partial,
)
from hpcves.run.store import HDF5_ERRORS, open_file, storage_bytes


def file_bytes(study: Study) -> int:
    """The size of a new campaign file of ``study``'s known cases: every sample and snapshot preallocated."""
    return METADATA_BYTES_PER_FILE + sum(storage_bytes(c.case) for c in study.cases)


def create_file(study: Study, path: Path, comm) -> None:
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


def add_stage(path: Path, comm, cases, stage: int, source: str) -> str:
    """Add a search (refine) stage's cases to a copy of the file that then replaces it, with the
    campaign file's text ``source`` (a refinement's budget may have been raised); "" or why it could not be."""
    def reserve():
        copy_for_change(path, sum(storage_bytes(c.case) for c in cases), f"adding stage {stage}'s {len(cases)} cases")

    return _change(path, comm, reserve, lambda h5: CampaignFile(h5).add_cases(cases, source),
                   f"cannot add stage {stage}'s cases", "the file is unchanged")


def grow_file(path: Path, comm, grown: Growth) -> str:
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
    and under mpio every object created is a collective operation that all ranks wait on (BENCHMARKS.md,
    "Creating a campaign file"); the ranks open the finished file together afterwards."""
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
