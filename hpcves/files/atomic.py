"""Structural changes of an hpcves file by replacement: the file at its path is always complete.

HDF5 changes a file's structure (new groups, datasets, attributes, sizes)
through a metadata cache that it writes back in pieces. If the process is
killed, or the disk fills up, in the middle of that, the metadata left on
disk no longer parse ("addr overflow", "unable to determine object type"),
and nothing can read the file again. So hpcves never changes the structure
of a file in place. It builds the new version under a temporary name next to
it (``<name>.partial``), either a new file or a copy of the old one, flushes
it to disk, and renames it over the old name, which POSIX makes atomic.

Whatever happens before the rename, the old file stays as it was. A stale
``.partial`` may be left behind; the next writer, holding the file's lock,
removes it. In place, hpcves writes only raw data into space that was
allocated when the file was made (checkpoints, time series: run/store.py).
That cannot move or break the metadata a reader parses, so a reader of a
live file always finds a whole file.

A full disk must never reach HDF5 itself: once a flush or a close has failed
with "No space left on device", HDF5 1.10 keeps the half-closed file and
crashes later (a segfault at the next collection or at exit; seen). So the
space a change needs -- estimated from above -- is reserved on disk
(``posix_fallocate``) before HDF5 opens the ``.partial``, starting from the
image of an empty HDF5 file; HDF5 accepts a file longer than what it has
allocated and trims the reservation when it closes the file.

The price is a copy of the whole file for each change of an existing file:
a search stage's new cases, or ``hpcves analyze`` storing its results
(0.6 to 0.85 s per GiB with its fsync, measured on the development machine's disk).
Replacement also gives the file a new inode, which breaks hard links; that
is one reason a file with hard links is refused for writing (lock.py).
"""
from __future__ import annotations

import errno
import functools
import os
import shutil
from pathlib import Path

from hpcves.config import not_a_regular_file
from hpcves.errors import (
    FileFormatError,
    StorageError,  # noqa: F401 -- raised here; callers import it from here too
)
from hpcves.files import faults

#: what a file needs beyond its datasets' raw bytes, per case (object headers, attributes, the config
#: text: 25 kB measured at N = 32, 128 and 256; 39 kB at N = 64 since the series carry units and
#: dimension scales, store.describe) and per file, with room to spare
METADATA_BYTES_PER_CASE = 56 * 1024
METADATA_BYTES_PER_FILE = 1 << 20


def partial_path(path) -> Path:
    """Where the next version of ``path`` is built."""
    path = Path(path)
    return path.with_name(path.name + ".partial")


#: the first bytes of an HDF5 file (with no user block, as hpcves writes them)
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def remove_partial(path) -> bool:
    """Remove a leftover ``.partial`` of ``path`` (call it holding the file's lock); True if there was one.

    Only what hpcves leaves there is removed: an HDF5 file, or the zeros of a reservation made before
    the file's first bytes were written (:func:`new_partial`). Anything else -- a user's file that
    happens to bear the name, a link, a directory -- is refused with a FileFormatError, not deleted
    (and not truncated by the next :func:`new_partial` either)."""
    partial = partial_path(path)
    if not os.path.lexists(partial):
        return False
    ours = not os.path.islink(partial) and os.path.isfile(partial)
    if ours:
        with open(partial, "rb") as f:
            head = f.read(len(HDF5_SIGNATURE))
        ours = head == HDF5_SIGNATURE or not head.strip(b"\0")
    if not ours:
        raise FileFormatError(f"{partial}: there, but not a file hpcves left (hpcves builds the next version "
                              f"of {Path(path).name} under that name): move it away, then run this again")
    try:
        os.unlink(partial)
        return True
    except FileNotFoundError:
        return False


def free_bytes(path) -> int:
    """Bytes free for an unprivileged writer on the file system of ``path`` (or of its directory)."""
    path = Path(path)
    directory = path if path.is_dir() else path.parent
    while not directory.exists() and directory != directory.parent:
        directory = directory.parent
    return shutil.disk_usage(directory).free


def size_text(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if abs(n) < 1000 or unit == "PB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.3g} {unit}"
        n /= 1000.0
    return ""  # pragma: no cover


def require_space(path, needed: float, what: str) -> None:
    """Refuse, before any work, what the file system of ``path`` has no room for (with the numbers)."""
    free = free_bytes(path)
    if needed > free:
        raise StorageError(f"{path}: {what} needs {size_text(needed)}, but only {size_text(free)} is free there; "
                           "free some space (or shorten the runs) and start again")


def fsync_file(path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def publish(partial, path) -> None:
    """Make the finished ``partial`` the file at ``path``: flush it to disk, rename it over ``path``.

    The rename is atomic, so a reader (or a crash) finds either the old file or the new one. The
    directory is flushed too, so that the rename itself survives a crash of the machine.
    """
    fsync_file(partial)
    faults.point("publish")
    os.replace(partial, path)
    try:
        fd = os.open(Path(path).parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass                                  # some file systems cannot flush a directory
    finally:
        os.close(fd)


#: the HDF5 formats a new file is made in (h5py's ``libver``): superblock version 2 (HDF5 1.8), which --
#: unlike 1.10's version 3 -- marks no file as open for writing, so that a file is read while it is
#: written (``hpcves status`` of a running campaign) and one whose writer was killed opens without
#: h5clear. What goes into it is written in HDF5 1.10's formats (run/store.py: OBJECT_FORMAT).
FILE_FORMAT = ("v108", "v108")


@functools.cache
def empty_hdf5_image(libver: tuple[str, str]) -> bytes:
    """The bytes of an HDF5 file with nothing in it, in the formats ``libver``, closed (made in memory:
    HDF5 writes nothing to disk; an image taken while the file is open has the superblock of an open
    file, whose checksum fails)."""
    import io

    import h5py

    image = io.BytesIO()
    with h5py.File(image, "w", libver=libver):
        pass
    return image.getvalue()


def _reserve(fd: int, nbytes: int) -> None:
    """Allocate the first ``nbytes`` of the file on disk (a full disk says so here, not inside HDF5)."""
    try:
        os.posix_fallocate(fd, 0, max(int(nbytes), 1))
    except OSError as exc:
        if exc.errno not in (errno.EOPNOTSUPP, errno.EINVAL, errno.ENOSYS):
            raise                           # a file system that cannot reserve: the check above has to do


def new_partial(path, nbytes: float, what: str) -> Path:
    """An empty HDF5 file at ``<path>.partial`` with ``nbytes`` reserved for ``what`` is to go into it."""
    path = Path(path)
    partial = partial_path(path)
    require_space(path, nbytes, what)
    remove_partial(path)                  # debris of an earlier try; a user's file there is refused
    try:
        fd = os.open(partial, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        try:
            _reserve(fd, nbytes)
            os.pwrite(fd, empty_hdf5_image(FILE_FORMAT), 0)
        finally:
            os.close(fd)
    except OSError as exc:
        remove_partial(path)
        raise StorageError(f"{path}: cannot create it ({exc.strerror}); nothing was written") from None
    return partial


def copy_for_change(path, extra_bytes: float, what: str) -> Path:
    """Copy ``path`` to its ``.partial`` (the copy keeps the mode), with ``extra_bytes`` reserved after
    it for ``what``, and return that; the space is checked first."""
    path = Path(path)
    partial = partial_path(path)
    size = path.stat().st_size
    require_space(path, size + extra_bytes, what)
    remove_partial(path)                  # debris of an earlier try; a user's file there is refused
    try:
        shutil.copyfile(path, partial)
        shutil.copymode(path, partial)
        fd = os.open(partial, os.O_WRONLY)
        try:
            _reserve(fd, size + extra_bytes)
        finally:
            os.close(fd)
    except OSError as exc:
        remove_partial(path)
        raise StorageError(f"{path}: cannot copy it for {what} ({exc.strerror}); the file is unchanged") from None
    return partial


#: what hpcves keeps beside a file ``<name>``: ``<name>.lock`` (who writes it: lock.py), ``<name>.partial``
#: (its next version while that is built: here), ``<name>.jobs``, ``<name>.idle_jobs``,
#: ``<name>.progress_seen`` and ``<name>.status.json`` (a batch chain's counts and last status:
#: campaign/templates/slurm.sh); a figure or movie ``<stem>.<ext>`` is built as ``<stem>.partial.<ext>``
SIDE_SUFFIXES = (".lock", ".partial", ".jobs", ".idle_jobs", ".progress_seen", ".status.json")


def side_file_name(path) -> str:
    """Why ``path``'s name (or the name a symlink there leads to) is one hpcves gives a side file of
    another file, which a command on that file would truncate or delete ('' where it is none)."""
    for name in dict.fromkeys((Path(path).name, Path(os.path.realpath(path)).name)):
        for suffix in SIDE_SUFFIXES:
            if name.endswith(suffix) and len(name) > len(suffix):
                return f"'{suffix}' ends the names hpcves gives the files it keeps beside {name[:-len(suffix)]}"
        if Path(name).stem.endswith(".partial"):
            return f"'.partial{Path(name).suffix}' ends the names hpcves gives a figure or movie while it draws it"
    return ""


def check_output_path(path, new: bool = True) -> None:
    """Refuse an output path that cannot be a file before any work: a directory, a device or other
    special file (renaming the new file over it would replace it), a path under a file, or (``new``:
    a file this command makes) a name hpcves gives its side files (:data:`SIDE_SUFFIXES`: another
    command would take it for its own and truncate or delete it)."""
    path = Path(path)
    side = side_file_name(path) if new else ""
    if side:
        raise StorageError(f"{path}: {side} (a command on that file would take this one for its own and "
                           "overwrite or delete it); choose another name")
    if path.is_dir():
        raise StorageError(f"{path}: is a directory, not a file")
    if path.exists() and not_a_regular_file(path):
        raise StorageError(f"{path}: {not_a_regular_file(path)}, not a file")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise StorageError(f"{path}: {parent} is not a directory")
            break
