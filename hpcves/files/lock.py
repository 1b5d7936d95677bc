"""Who may write a campaign file: byte-range locks on ``<real path>.lock``, held by every rank.

A writer -- a campaign's rank 0, or ``hpcves analyze`` storing its results --
first locks the whole lock file, which fails while any process holds any
part of it, then keeps byte 0 only; every other rank r of a campaign then
locks byte r. So a second writer is refused as long as *any* process of the
first is alive, also while ranks linger after ``mpirun`` itself was killed
(Open MPI puts each rank in a process group of its own, so ``kill -9 -PGID``
of mpirun leaves the ranks running for about a second).

The locks are Linux open-file-description locks (``F_OFD_SETLK``; POSIX
``lockf`` where those do not exist): the kernel drops them when the process
dies, even by SIGKILL, so a killed campaign can always be resumed, and two
opens in one process conflict like two processes do.

The lock file is named after the file's *real* path (symlinks and other
spellings resolved), so every route to the file finds the same lock. A hard
link is another name for the same file that no path resolution can see;
a file with more than one is therefore refused for writing. The lock file
stays behind, empty (removing it would let two writers lock two different
files of the same name).
"""
from __future__ import annotations

import errno
import fcntl
import logging
import os
import socket
import struct
import time
from pathlib import Path

from hpcves.errors import LockError  # noqa: F401 -- raised here; callers import it from here too

log = logging.getLogger(__name__)

_FLOCK = "@hhqqi0q"      # struct flock: l_type, l_whence, l_start, l_len, l_pid (Linux, 64-bit off_t)
_UNSUPPORTED = (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL)


def real_path(path) -> Path:
    """The file's path with every symlink resolved (the file itself need not exist; a link may point
    to where it will be). A link that leads back to itself is refused."""
    path = os.fspath(path)
    if os.path.islink(path):
        try:
            os.stat(path)
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                raise LockError(f"{path}: a symbolic link that leads back to itself") from None
    return Path(os.path.realpath(path))


def _ofd(fd: int, command: int, kind: int, start: int, length: int) -> tuple:
    answer = fcntl.fcntl(fd, command, struct.pack(_FLOCK, kind, os.SEEK_SET, start, length, 0))
    return struct.unpack(_FLOCK, answer)


def _lock(fd: int, start: int, length: int) -> None:
    """Exclusive lock on bytes [start, start + length) (length 0: to the end), without waiting.

    Raises BlockingIOError when another holder has part of it.
    """
    if hasattr(fcntl, "F_OFD_SETLK"):
        try:
            _ofd(fd, fcntl.F_OFD_SETLK, fcntl.F_WRLCK, start, length)
            return
        except PermissionError:                 # EACCES: some systems' way of saying "held"
            raise BlockingIOError(errno.EAGAIN, "locked") from None
        except OSError as exc:
            if exc.errno != errno.EINVAL:       # EINVAL: a kernel without OFD locks
                raise
    fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB, length, start)


def _unlock(fd: int, start: int, length: int) -> None:
    if hasattr(fcntl, "F_OFD_SETLK"):
        try:
            _ofd(fd, fcntl.F_OFD_SETLK, fcntl.F_UNLCK, start, length)
            return
        except OSError as exc:
            if exc.errno != errno.EINVAL:
                raise
    fcntl.lockf(fd, fcntl.LOCK_UN, length, start)


def _held_byte(fd: int) -> int | None:
    """The first byte some other holder has locked, or None (also where that cannot be asked)."""
    if not hasattr(fcntl, "F_OFD_GETLK"):
        return None
    try:
        kind, _, start, _, _ = _ofd(fd, fcntl.F_OFD_GETLK, fcntl.F_WRLCK, 0, 0)
    except OSError:
        return None
    return None if kind == fcntl.F_UNLCK else start


#: how a lock file begins while its writer holds it (it is empty otherwise): anything else there is some
#: other file under a lock file's name, which a writer must not truncate
NOTE_START = b"pid "


class CampaignLock:
    """The write lock of one hpcves file -- a campaign's or a run's: ``acquire`` (the writer), ``join``
    (a campaign's other ranks), ``release``. ``what`` names the writer in its note ("hpcves run")."""

    def __init__(self, path, what: str = ""):
        self.given = Path(path)                  # as the user spelled it (for messages)
        self.what = what
        self.target = real_path(path)
        self.path = self.target.with_name(self.target.name + ".lock")
        self._fd = None
        self.owner = False

    def _open(self) -> int | None:
        """The lock file's descriptor; None where the file system cannot lock (a warning says so)."""
        directory = self.path.parent
        if directory.exists() and not directory.is_dir():
            raise LockError(f"{self.given}: {directory} is not a directory")
        try:
            directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise LockError(f"{self.given}: cannot create the directory {exc.filename or directory} "
                            f"({exc.strerror})") from None
        if os.path.lexists(self.path) and not os.path.isfile(self.path):
            raise LockError(f"{self.given}: {self.path}, where its lock belongs, is not a regular file; "
                            "move it away")
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise LockError(f"{self.given}: cannot create the lock file {self.path} ({exc.strerror}); "
                            "is the directory writable?") from None
        try:
            size, head = os.fstat(fd).st_size, os.pread(fd, len(NOTE_START), 0)
        except OSError:
            size, head = 0, b""
        if size and head != NOTE_START:
            os.close(fd)
            raise LockError(f"{self.given}: {self.path}, where its lock belongs, holds {size} bytes of another "
                            "file (not a lock note), which locking would truncate; move it away")
        return fd

    def acquire(self) -> "CampaignLock":
        """Become the one writer of the file; refused while any process of another writer lives."""
        if self.target.is_dir():
            raise LockError(f"{self.given}: is a directory, not a file")
        fd = self._open()
        try:
            _lock(fd, 0, 0)
        except BlockingIOError:
            message = self._refusal(fd)
            os.close(fd)
            raise LockError(message) from None
        except OSError as exc:
            if exc.errno not in _UNSUPPORTED:
                os.close(fd)
                raise LockError(f"{self.given}: cannot lock {self.path} ({exc.strerror})") from None
            log.warning("cannot lock %s (%s); make sure no other campaign writes this file", self.path,
                        exc.strerror)
            os.close(fd)
            fd = None
        if fd is not None:
            try:
                _unlock(fd, 1, 0)                # keep byte 0; the other ranks lock theirs
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()}, since "
                          f"{time.strftime('%Y-%m-%d %H:%M:%S')}{f' ({self.what})' if self.what else ''}".encode(), 0)
            except OSError:                      # a full disk: the lock holds without the note
                pass
        self._fd, self.owner = fd, True
        try:
            links = self.target.stat().st_nlink
        except OSError:
            links = 1
        if links > 1:
            self.release()
            raise LockError(f"{self.given}: has {links} hard links (names); another campaign could write it "
                            "under another name without seeing this one's lock. Keep one name (rm the others; "
                            "cp makes an independent copy)")
        return self

    def join(self, rank: int) -> "CampaignLock":
        """Rank ``rank`` (> 0) of the writer's job holds byte ``rank`` for as long as it lives."""
        try:
            fd = os.open(self.path, os.O_RDWR)
        except OSError:
            return self                          # rank 0 warned already, or the file system has no locks
        try:
            _lock(fd, rank, 1)
        except BlockingIOError:
            os.close(fd)
            raise LockError(f"{self.given}: rank {rank} cannot take its part of the lock {self.path}: "
                            "another process holds it") from None
        except OSError:
            os.close(fd)
            return self
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            if self.owner:
                try:
                    os.ftruncate(self._fd, 0)
                except OSError:
                    pass
            os.close(self._fd)                   # closing drops the lock
            self._fd = None

    def __enter__(self) -> "CampaignLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()

    def _refusal(self, fd: int) -> str:
        holder = os.pread(fd, 200, 0).decode(errors="replace").strip()
        byte = _held_byte(fd)
        if byte is not None and byte > 0:
            who = (f"rank {byte} of the campaign started by {holder} is still running" if holder else
                   f"rank {byte} of an earlier campaign is still running")
            return (f"{self.given}: {who} (its rank 0 has ended: the job is winding down or was killed); "
                    "wait until all its ranks have exited")
        return (f"{self.given}: another hpcves process (a run, a campaign or analyze) is writing this file "
                f"({holder or 'another process'}); wait for it or stop it first")


def writer(path) -> str | None:
    """Who holds the write lock of ``path`` now ("pid ... on host, since ..."), or None. Takes no lock."""
    lock = CampaignLock(path)
    try:
        fd = os.open(lock.path, os.O_RDONLY)
    except OSError:
        return None
    try:
        byte = _held_byte(fd)
        if byte is None:
            return None
        holder = os.pread(fd, 200, 0).decode(errors="replace").strip() or "another process"
        return holder if byte == 0 else f"rank {byte} of a campaign ({holder})"
    finally:
        os.close(fd)
