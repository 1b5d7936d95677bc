"""The file of one run (``hpcves run``): made whole or not at all, reopened for a resume, run.

``create_case_file`` lays the case out under ``<path>.partial`` and renames it (files/atomic.py),
so a kill or a full disk never leaves a half-made file; ``open_for_resume`` refuses a damaged
file before any work; ``run_file`` runs (or continues) the case in such a file. Both hold the
file's write lock (files/lock.py, the one a campaign and ``hpcves analyze`` take) from before the
file is made or replaced until it is closed, so no other hpcves command writes or replaces it
meanwhile. The CLI and the Python API (hpcves.api) both go through here.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import h5py

from hpcves.files.atomic import (
    METADATA_BYTES_PER_FILE,
    StorageError,
    check_output_path,
    new_partial,
    publish,
    remove_partial,
)
from hpcves.files.lock import CampaignLock
from hpcves.model.params import Case
from hpcves.run import runner
from hpcves.run.store import CaseStore, FileFormatError, open_file, refuse_unopenable, safe_flush, storage_bytes
from hpcves.run.stored import read_stored_start


@dataclass
class OpenRun:
    """A run file open r+ and its write lock, held until :meth:`close`."""

    h5: h5py.File
    lock: CampaignLock

    @property
    def path(self) -> str:
        return self.h5.filename

    def close(self) -> None:
        try:
            self.h5.close()
        except (OSError, RuntimeError):
            pass                    # a refused write, reported by the caller
        finally:
            self.lock.release()


def _locked(path) -> CampaignLock:
    """The write lock of ``path`` for ``hpcves run``, refused while another hpcves process writes it."""
    return CampaignLock(path, "hpcves run").acquire()


def create_case_file(path, case: Case, overwrite: bool = False) -> OpenRun:
    """The new file of one run, open r+ with its lock held: laid out under ``<path>.partial``, then
    renamed to ``path`` (atomic.py), so a kill or a full disk never leaves a half-made file at ``path``."""
    path = Path(path)
    check_output_path(path)
    if path.exists() and not overwrite:
        raise FileFormatError(f"{path}: exists already (use --overwrite to replace it)")
    if case.physics.initial_shape == "stored":      # a start that cannot be read: refused before any file
        read_stored_start(case.physics)
    if not path.absolute().parent.is_dir():         # (the lock would make it)
        raise StorageError(f"{path}: cannot create it (its directory {path.absolute().parent} does not exist); "
                           "nothing was written")
    lock = _locked(path)
    try:
        return OpenRun(_create(path, case), lock)
    except BaseException:
        lock.release()
        raise


def _create(path: Path, case: Case):
    """The file of :func:`create_case_file`, made under ``<path>.partial`` and renamed (its lock held)."""
    if path.exists():                       # nor while an older hpcves's run has it open (HDF5's own lock)
        try:
            open_file(path, "r+").close()
        except FileFormatError as exc:
            if "in use" in str(exc):
                raise
    partial = new_partial(path, storage_bytes(case) + METADATA_BYTES_PER_FILE,
                          "the run's file (every sample and snapshot preallocated)")
    try:
        h5 = open_file(partial, "r+")
        try:
            CaseStore.create(h5, case)
        finally:
            h5.close()
        publish(partial, path)
    except (OSError, RuntimeError) as exc:
        remove_partial(path)
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc).splitlines()[0]
        raise StorageError(f"{path}: cannot create it ({reason}); nothing was written") from None
    except BaseException:
        remove_partial(path)
        raise
    return open_file(path, "r+")


def open_for_resume(path) -> OpenRun:
    """The file of an earlier run, open r+ with its lock held, after ``CaseStore.problems`` found
    nothing wrong in it."""
    check_output_path(path, new=False)
    if not Path(path).exists():                 # refused before a lock file is made beside it
        raise FileFormatError(f"{path}: no such file")
    refuse_unopenable(path, "r+")
    lock = _locked(path)
    try:
        h5 = open_file(path, "r+")
    except BaseException:
        lock.release()
        raise
    try:
        store = CaseStore.open(h5, where=str(path))
        problems = store.problems(resuming=True)
        if problems:
            raise FileFormatError(f"{path}: damaged, not resumed ({'; '.join(problems[:3])}"
                                  + (f"; {len(problems) - 3} more" if len(problems) > 3 else "") + ")")
    except BaseException:
        OpenRun(h5, lock).close()
        raise
    return OpenRun(h5, lock)


def run_file(opened: OpenRun, *, resume: bool, **options) -> runner.Outcome:
    """Run (or with ``resume`` continue) the case of an open run file, then close it and release its
    lock; ``options`` go to :func:`hpcves.run.runner.run` (progress, stop_requested, max_steps, analysis)."""
    try:
        return runner.run(CaseStore(opened.h5), safe_flush(opened.h5), resume=resume, **options)
    except StorageError as exc:
        raise StorageError(f"{exc}; stopped, the last valid checkpoint is kept: free some space, then "
                           f"hpcves run --resume {opened.path}") from None
    finally:
        opened.close()
