"""The file of one run (``hpcves run``): made whole or not at all, reopened for a resume, run.

``create_case_file`` lays the case out under ``<path>.partial`` and renames it (files/atomic.py),
so a kill or a full disk never leaves a half-made file; ``open_for_resume`` refuses a damaged
file before any work; ``run_file`` runs (or continues) the case in such a file. The CLI and the
Python API (hpcves.api) both go through here.
"""
from __future__ import annotations

from pathlib import Path

from hpcves.files.atomic import (
    METADATA_BYTES_PER_FILE,
    StorageError,
    check_output_path,
    new_partial,
    publish,
    remove_partial,
)
from hpcves.model.params import Case
from hpcves.run import runner
from hpcves.run.store import CaseStore, FileFormatError, open_file, safe_flush, storage_bytes


def create_case_file(path, case: Case, overwrite: bool = False):
    """The new file of one run, open r+: laid out under ``<path>.partial``, then renamed to ``path``
    (atomic.py), so a kill or a full disk never leaves a half-made file at ``path``."""
    path = Path(path)
    check_output_path(path)
    if path.exists() and not overwrite:
        raise FileFormatError(f"{path}: exists already (use --overwrite to replace it)")
    if path.exists():                       # replaced only if no run writes it (HDF5's own lock)
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


def open_for_resume(path):
    """The file of an earlier run, open r+, after ``CaseStore.problems`` found nothing wrong in it."""
    check_output_path(path)
    h5 = open_file(path, "r+")
    try:
        store = CaseStore.open(h5, where=str(path))
        problems = store.problems(resuming=True)
        if problems:
            raise FileFormatError(f"{path}: damaged, not resumed ({'; '.join(problems[:3])}"
                                  + (f"; {len(problems) - 3} more" if len(problems) > 3 else "") + ")")
    except BaseException:
        h5.close()
        raise
    return h5


def run_file(h5, *, resume: bool, **options) -> runner.Outcome:
    """Run (or with ``resume`` continue) the case of an open run file, then close it; ``options``
    go to :func:`hpcves.run.runner.run` (progress, stop_requested, max_steps, analysis)."""
    path = h5.filename
    try:
        return runner.run(CaseStore(h5), safe_flush(h5), resume=resume, **options)
    except StorageError as exc:
        raise StorageError(f"{exc}; stopped, the last valid checkpoint is kept: free some space, then "
                           f"hpcves run --resume {path}") from None
    finally:
        try:
            h5.close()
        except (OSError, RuntimeError):
            pass                    # a refused write, reported by the caller
