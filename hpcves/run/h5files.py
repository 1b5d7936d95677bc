"""Opening and reading the HDF5 files hpcves writes: one clear error for every way a file can fail to
open, damaged metadata turned into FileFormatError (:func:`reading`), refused writes into
StorageError (:func:`safe_flush`, the CaseStore writes), the HDF5 object formats and caches of the
files, and attributes as Python values."""
from __future__ import annotations

import contextlib
import functools

import h5py
import numpy as np

from hpcves.config import not_a_regular_file
from hpcves.errors import FileFormatError, HpcvesError
from hpcves.files.atomic import HDF5_SIGNATURE, StorageError

#: what h5py raises when the file under it is damaged (unreadable metadata, objects of the wrong kind);
#: hpcves's own errors are ValueErrors too: catch them first where they have to go through (see :func:`reading`)
HDF5_ERRORS = (OSError, KeyError, RuntimeError, ValueError, TypeError, IndexError, AttributeError)


@contextlib.contextmanager
def reading(where: str):
    """Reading a file: what h5py raises from damaged metadata becomes one FileFormatError naming
    ``where``; hpcves's own errors (errors.HpcvesError) pass unchanged."""
    try:
        yield
    except HpcvesError:
        raise
    except HDF5_ERRORS as exc:
        raise FileFormatError(f"{where}: damaged file ({type(exc).__name__}: {_first_line(exc)})") from None


def _writes(method):
    """A CaseStore write: a refusal of the file system (full disk, quota, I/O error) becomes a StorageError."""
    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        try:
            return method(self, *args, **kwargs)
        except (OSError, RuntimeError) as exc:
            raise StorageError(f"{self._place.filename}: cannot write {self.where} "
                               f"({_first_line(exc)})") from exc
    return wrapper


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def safe_flush(h5):
    """h5py ``File.flush`` that raises StorageError when the file system refuses the write."""
    def flush():
        try:
            h5.flush()
        except (OSError, RuntimeError) as exc:
            raise StorageError(f"{h5.filename}: cannot write ({_first_line(exc)})") from exc
    return flush


def refuse_unopenable(path, mode: str = "r") -> None:
    """Refuse an existing ``path`` that is no file to open as HDF5: a device, a pipe, a socket (h5py
    writes to them; /dev/null crashed it), or, to read, an empty file (HDF5 1.10 opens one r+ and
    writes a superblock into it). Nothing is opened, locked or made."""
    import os

    if not os.path.exists(path):
        return
    kind = not_a_regular_file(path)
    if kind:
        raise FileFormatError(f"{path}: {kind}, not a file")
    if mode in ("r", "r+") and os.path.getsize(path) == 0:
        raise FileFormatError(f"{path}: empty (0 bytes), not an HDF5 file")


def open_file(path, mode: str, **kwargs):
    """h5py.File(path, mode, **kwargs) with one clear message for every way that can fail."""
    import errno
    import os

    path = os.fspath(path)
    if os.path.isdir(path):
        raise FileFormatError(f"{path}: is a directory, not a file")
    if os.path.islink(path) and not os.path.exists(path):
        try:
            os.stat(path)
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                raise FileFormatError(f"{path}: a symbolic link that leads back to itself") from None
    if mode in ("r", "r+") and not os.path.exists(path):
        raise FileFormatError(f"{path}: no such file")
    refuse_unopenable(path, mode)
    if mode in ("w-", "x") and os.path.exists(path):
        raise FileFormatError(f"{path}: exists already (use --overwrite to replace it)")
    kwargs.setdefault("rdcc_nbytes", CHUNK_CACHE_BYTES)
    if mode in ("r+", "a") and superblock_version(path) >= 2:
        kwargs.setdefault("libver", OBJECT_FORMAT)
    try:
        h5 = h5py.File(path, mode, **kwargs)
    except OSError as exc:
        text = str(exc)
        if "signature" in text or "truncated" in text.lower() or "eof" in text.lower():
            raise FileFormatError(f"{path}: not a readable HDF5 file (corrupt or truncated?)") from None
        if "unable to lock" in text.lower() or getattr(exc, "errno", None) in (errno.EAGAIN, errno.EWOULDBLOCK):
            raise FileFormatError(f"{path}: in use by another process (HDF5 file lock)") from None
        if exc.errno:                      # the system's reason, without HDF5's page of detail
            raise FileFormatError(f"{path}: cannot open as HDF5 ({os.strerror(exc.errno)})") from None
        raise FileFormatError(f"{path}: cannot open as HDF5 ({_first_line(exc)})") from None
    if mode != "r" and kwargs.get("driver") != "mpio":
        fixed_metadata_cache(h5)
    return h5


#: the HDF5 formats of what is written into a file made by hpcves (superblock version 2:
#: atomic.FILE_FORMAT): HDF5 1.10's, whose chunk indexes (fixed and extensible arrays) find a chunk in
#: constant time where 1.8's B-tree reads its nodes from the file on every write of a case (a quarter
#: of relay's rank 0 at 5000 tiny cases), and whose metadata carry checksums. Readable by HDF5 >= 1.10
#: (2016), netCDF-C built on it, h5py and h5netcdf. An older file (superblock 0) keeps the formats it was
#: written in: HDF5 1.10.8 crashes copying an object whose attributes 1.10's formats store densely, and
#: campaign format 1 copies a group per case (stamp.py).
OBJECT_FORMAT = ("v110", "v110")


def superblock_version(path) -> int:
    """The version of the HDF5 superblock at the start of the file at ``path`` (-1: none there)."""
    try:
        with open(path, "rb") as f:
            head = f.read(9)
    except OSError:
        return -1
    return head[8] if len(head) == 9 and head[:8] == HDF5_SIGNATURE else -1


#: HDF5's chunk cache of every file opened (h5py's rdcc_nbytes): none. A campaign file's blocks keep one
#: case a chunk; without a cache a write goes straight to the selected bytes of the chunk, as a
#: contiguous dataset's does (and as parallel HDF5 always writes). With HDF5's default 1 MiB a dataset,
#: every flush walked the cached chunks of all of them: a campaign of tiny cases in one process took
#: 18 ms a case after 250 cases and 29 ms after 1000
CHUNK_CACHE_BYTES = 0


#: the size of HDF5's metadata cache for a file written by one process (HDF5 starts at 2 MiB)
METADATA_CACHE_BYTES = 256 * 1024


def fixed_metadata_cache(h5, size: int = METADATA_CACHE_BYTES) -> None:
    """Keep HDF5's metadata cache of ``h5`` at ``size`` bytes.

    HDF5 grows the cache (to 32 MiB) when its hit rate falls, as it does when one process writes
    many cases in turn (rank 0 under relay); every flush walks all of its entries
    (H5C_set_slist_enabled) -- tiny cases hold ~300-byte entries, so ~10^5 of them. Kept small the
    walk stays short; what is evicted is read again from the page cache (docs/design.md).
    """
    config = h5.id.get_mdc_config()
    config.set_initial_size = True
    config.initial_size = config.min_size = config.max_size = size
    config.incr_mode = config.flash_incr_mode = config.decr_mode = 0     # H5C_incr__off, ...
    h5.id.set_mdc_config(config)


def attr_text(value) -> str:
    """An HDF5 string attribute as str (h5py returns bytes for fixed-length strings)."""
    return value.decode() if isinstance(value, bytes) else str(value)


def attr_integer(value):
    """An integer attribute (a format version, a count) as int; None where it holds anything else
    (1.5, a string): int() would round 1.5 to a version this hpcves reads."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        return None
    return int(value)


def attr_shown(value) -> str:
    """An attribute as a message shows it: text quoted (the string '1' is not the version 1)."""
    return repr(attr_text(value)) if isinstance(value, (str, bytes)) else str(value)
