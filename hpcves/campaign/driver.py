"""Running a study on MPI: :func:`run_campaign`, called on every rank.

Rank 0 takes the file's lock and decides to create the file, continue it or grow it to the study
(:func:`prepare_file`, growth.py); the other ranks join the lock; then the stages run (stages.py),
their cases handed out by rank 0 (scheduler.py), and every change of the file's structure is made
whole or not at all (structure.py).

File access. With one process the file is opened with the default driver.
With several ranks and an h5py built with MPI every rank opens it with the
``mpio`` driver; the structure is laid out up front by rank 0 alone with serial
HDF5 (collectively, every object created waits on all ranks: BENCHMARKS.md), under a
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
import time
from pathlib import Path
from typing import Callable

from hpcves.campaign.access import choose_io, file_access
from hpcves.campaign.file import CampaignFile
from hpcves.campaign.growth import Growth, growth
from hpcves.campaign.polling import bcast
from hpcves.campaign.scheduler import TAG_REPLY, TAG_REQUEST
from hpcves.campaign.stages import Summary, run_stages
from hpcves.campaign.state import CampaignRun
from hpcves.campaign.structure import file_bytes, grow_file
from hpcves.campaign.study import Study
from hpcves.errors import HpcvesError
from hpcves.files.atomic import (
    StorageError,
    check_output_path,
    copy_for_change,
    partial_path,
    publish,
    remove_partial,
    require_space,
)
from hpcves.files.lock import CampaignLock, LockError, real_path
from hpcves.run.store import HDF5_ERRORS, FileFormatError, open_file, reading, refuse_unopenable

log = logging.getLogger(__name__)


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
        campaign.stored_text(str(path))            # what later replays, labels and analyses it: whole
        grown = growth(study, campaign, str(path))
        damaged = campaign.damaged(grown.study)
    if damaged:
        shown = "; ".join(f"case {case_id}: {problems[0]}" for case_id, problems in damaged[:3])
        more = f"; {len(damaged) - 3} more" if len(damaged) > 3 else ""
        raise FileFormatError(f"{path}: {len(damaged)} damaged case{'s' * (len(damaged) != 1)}, not resumed "
                              f"({shown}{more}); hpcves status lists them; --overwrite starts the study over")
    return grown


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
    lock = CampaignLock(given, "hpcves campaign")
    verdict = None
    if rank == 0:
        try:
            check_output_path(given)                               # before a lock file is made beside it
            refuse_unopenable(given, "r+" if resume else "a")
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
            refused = grow_file(path, comm, grown)
            if refused:
                raise StorageError(refused)
        run = CampaignRun(study, path, comm, access, retry_failed, stop_flag, display, announce, on_stage, start)
        return run_stages(run, mode)
    finally:
        lock.release()
