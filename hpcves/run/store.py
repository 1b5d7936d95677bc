"""HDF5 storage of one case: parameters, time series, snapshots, checkpoints.

A case lives in an HDF5 group -- the file's root for ``hpcves run``, one
``cases/<id>`` group per case in a campaign file of format 1 -- or is one row of
the same datasets with a leading case dimension (campaign format 2: run/blocks.py;
:class:`CaseStore` reads and writes either through its place). Layout (see
docs/file-format.md):

    attrs          format = "hpcves-case", format_version, hpcves_version,
                   config (the full case as TOML), one attribute per parameter
                   ("physics.shear_rate", ...), N, capacities
    status         int8 scalar: 0 pending, 1 running, 2 finished, 3 failed, 4 interrupted
    message        fixed-length string: failure reason / last note
    traceback      fixed-length string: the traceback of a case that raised (absent in
                   files written before it existed; readers treat that as empty)
    progress       float64 [t, t_end, wall_seconds, steps_per_second], wall summed
                   over every call that advanced the case
    decision       float64 [regime code, t, step]: what stopped a run with
                   run.until_decided (decision.py; code 0: not decided) -- absent in
                   files written before it existed
    timeseries/    one preallocated dataset per series (NaN-filled), ``length``
                   counts the valid rows; centroid has shape (n, 2)
    snapshots/     t, shift and one (n, N) dataset per field; ``length`` counts
    checkpoint/    slot0/, slot1/: the solver State; each has ``meta`` =
                   [valid, step, n_samples, n_snapshots] and ``digest``, the checksum of
                   each array, the scalars and meta[1:] (format 5), and ``records``, the
                   checksums of the series and snapshot rows it builds on -- the first
                   n_samples of each series, the first n_snapshots of each snapshot
                   record, in the order of timeseries/digest then snapshots/digest (format 6)
    timeseries/digest, snapshots/digest
                   the checksums of the valid part of every series and snapshot
                   field, written when the case ends (format 5)

Everything that changes during a run is a dataset written in place (never an
attribute, never a resize): that keeps the writes independent in parallel
HDF5, and writes of raw data to preallocated space are the safest thing to be
doing when a process dies. A checkpoint goes to the slot *not* holding the
newest valid one: its ``meta`` is marked invalid first, the state written,
flushed, then marked valid -- so a crash in the middle leaves the previous
checkpoint intact and recognisably the newest valid one. Its checksums are
written before it is marked valid; a slot that fails them -- or whose series and
snapshots, the rows a resume keeps, fail theirs -- is passed over for the other
one when a run resumes (:meth:`CaseStore.read_checkpoint`), and written first.
"""
from __future__ import annotations

import contextlib
import enum
import functools
import hashlib
import math
from dataclasses import dataclass
from typing import Protocol

import h5py
import numpy as np

from hpcves.config import case_from_toml, case_to_toml, not_a_regular_file
from hpcves.errors import FileFormatError, HpcvesError
from hpcves.files import faults
from hpcves.files.atomic import METADATA_BYTES_PER_CASE, StorageError
from hpcves.model.params import Case, ConfigError
from hpcves.numerics.spectral import Spectral, resample
from hpcves.run.decision import REGIMES_BY_CODE
from hpcves.run.diagnostics import OPTIONAL_SERIES, SERIES, SERIES_ATTRS, SNAPSHOT_ATTRS, SNAPSHOT_FIELDS
from hpcves.run.schedule import clock
from hpcves.solver.timestepping import State
from hpcves.version import __version__

FORMAT = "hpcves-case"
FORMAT_VERSION = 6                  # 6: a checkpoint's checksums of the rows it builds on; 5: checksums of
                                    # the checkpoints and of an ended case's data
READS_VERSIONS = (2, 3, 4, 5, 6)    # 4: checkpoints hold their N (N adapting) and the resize memory; 3: t,
                                    # the step controller and level n-2; 2: fixed-step checkpoints
                                    # (t = step dt); 1 held psi at material labels
#: the first format whose cases carry checksums
DIGESTS_SINCE = 5
#: the first format whose checkpoints carry the checksums of the series and snapshots they build on
RECORDS_SINCE = 6
MESSAGE_BYTES = 4096
TRACEBACK_BYTES = 16384

class Status(enum.IntEnum):
    """A case's status: its int8 code in the file, its name in tables (``str(status)``: "model limit")."""

    PENDING = 0
    RUNNING = 1
    FINISHED = 2
    FAILED = 3
    INTERRUPTED = 4
    MODEL_LIMIT = 5

    def __str__(self) -> str:
        return self.name.lower().replace("_", " ")


PENDING, RUNNING, FINISHED, FAILED, INTERRUPTED, MODEL_LIMIT = Status
NOT_DECIDED = (0.0, math.nan, -1.0)
STATUS_NAMES = {status: str(status) for status in Status}
#: statuses of a case that is over: it is not run again (FAILED is with --retry-failed). MODEL_LIMIT:
#: psi left the range where the linear bending law is physics (runner.beyond_model) -- an outcome of
#: the model, not a fault of the numerics
ENDED = (FINISHED, FAILED, MODEL_LIMIT)
ENDED_NAMES = tuple(STATUS_NAMES[s] for s in ENDED)

# scalars of a State, stored as one float64 vector (complex values as two entries), and the
# arrays, per format version (version 2 files are fixed-step runs: see CaseStore.read_checkpoint)
_SCALAR_LAYOUTS = {
    2: (("center", 2), ("shift", 1), ("area_correction", 1), ("prev_center", 2),
        ("prev_shift", 1), ("prev_rate_center", 2), ("prev_rate_shift", 1)),
}
_SCALAR_LAYOUTS[3] = _SCALAR_LAYOUTS[2] + (("t", 1), ("dt_prev", 1), ("dt_prev2", 1), ("error", 1), ("dt_next", 1))
_SCALAR_LAYOUTS[4] = _SCALAR_LAYOUTS[3] + (("quiet_since", 1), ("N", 1))
_SCALAR_LAYOUTS[5] = _SCALAR_LAYOUTS[6] = _SCALAR_LAYOUTS[4]
_ARRAYS = {2: State.ARRAYS[:6], 3: State.ARRAYS, 4: State.ARRAYS, 5: State.ARRAYS, 6: State.ARRAYS}
assert _ARRAYS[2] == ("theta", "psi", "prev_theta", "prev_psi", "prev_rate_theta", "prev_rate_psi")
_SCALAR_LAYOUT = _SCALAR_LAYOUTS[FORMAT_VERSION]
#: the per-snapshot records, in the order of snapshots/digest
SNAPSHOT_RECORDS = ("t", "shift") + SNAPSHOT_FIELDS
_N_SCALARS = sum(n for _, n in _SCALAR_LAYOUT)


@dataclass(frozen=True)
class Column:
    """Where a record lies inside a packed array (campaign format 3: run/blocks.py): indices ``first`` to
    ``first + width`` along axis ``axis`` of the case's part of ``array``; ``squeezed``: the record has no
    axis there (width 1). A series is a column of ``timeseries/series`` (centroid two), a snapshot field
    a slice of ``snapshots/fields``, a checkpoint array a row of ``checkpoint/<slot>/arrays``."""

    array: str
    axis: int
    first: int
    width: int = 1
    squeezed: bool = True

    def shape(self, packed: tuple) -> tuple | None:
        """The record's shape, from the case's part of the packed array's (None: it lies outside)."""
        if len(packed) <= self.axis or packed[self.axis] < self.first + self.width:
            return None
        return packed[:self.axis] + (() if self.squeezed else (self.width,)) + packed[self.axis + 1:]

    def place(self, first: tuple, count: tuple) -> tuple[tuple, tuple]:
        """A hyperslab of the record (first, count) as one of the packed array."""
        a = self.axis
        if self.squeezed:
            return first[:a] + (self.first,) + first[a:], count[:a] + (1,) + count[a:]
        return (first[:a] + (self.first + first[a],) + first[a + 1:], count)

    def index(self) -> tuple:
        """Where the record lies in a numpy array shaped as the packed array's selected rows."""
        chosen = self.first if self.squeezed else slice(self.first, self.first + self.width)
        return (slice(None),) * self.axis + (chosen,)


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
    return head[8] if len(head) == 9 and head[:8] == b"\x89HDF\r\n\x1a\n" else -1


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


def stored_case(config: str, where: str) -> Case:
    """The case of a stored ``config`` text (of the group ``where``)."""
    try:
        return case_from_toml(config, source=f"{where} config", stored=True)
    except ConfigError as exc:
        raise FileFormatError(str(exc)) from None


def stored_N(case: Case) -> int:
    """The width of a case's snapshots and checkpoint arrays: N, or N_max when N adapts (a
    checkpoint holds its N values first; snapshots are resampled to the width: exact for a field
    resolved on the run's grid)."""
    return case.numerics.N_max or case.numerics.N


def capacities(case: Case) -> tuple[int, int]:
    """Rows to preallocate for samples and snapshots (schedule.py: every cadence time, plus one)."""
    return clock(case).capacities()


def raw_bytes(case: Case) -> int:
    """The bytes :meth:`CaseStore.create` allocates for a case's datasets (all of them, up front)."""
    n_samples, n_snapshots = capacities(case)
    N = stored_N(case)
    series = (len(SERIES) + 1) * n_samples + 2               # centroid has two columns (+ xy)
    snapshots = (2 + len(SNAPSHOT_FIELDS) * N) * n_snapshots + N      # + alpha
    checkpoints = 2 * (len(State.ARRAYS) * N + _N_SCALARS + 4 + len(SERIES) + len(SNAPSHOT_RECORDS))
    fixed = 1 + MESSAGE_BYTES + TRACEBACK_BYTES + 4 * 8 + 2 * 8 + 3 * 8
    return 8 * (series + snapshots + checkpoints) + fixed


def storage_bytes(case: Case) -> int:
    """What one case takes in a file: its datasets plus their metadata (atomic.METADATA_BYTES_PER_CASE)."""
    return raw_bytes(case) + METADATA_BYTES_PER_CASE


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


def _early():
    """A dataset creation property list with storage allocated (and filled) at creation.

    Parallel HDF5 needs this for independent writes (allocation is collective);
    using it everywhere makes files from ``hpcves run``, serial and parallel
    campaigns interchangeable.
    """
    plist = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    plist.set_alloc_time(h5py.h5d.ALLOC_TIME_EARLY)
    return plist


def name_records(ts, snap) -> None:
    """``long_name`` and ``units`` on every series (group ``ts``) and snapshot field (``snap``) present."""
    for group, table in ((ts, SERIES_ATTRS), (snap, SNAPSHOT_ATTRS)):
        for name, (long_name, units) in table.items():
            if name in group:
                group[name].attrs["long_name"] = long_name
                group[name].attrs["units"] = units


def describe(ts, snap) -> None:
    """``long_name`` and ``units`` on every series and snapshot field, and HDF5 dimension scales:
    ``timeseries/sample`` (0, 1, ...) along the rows of every series, t among them
    (``timeseries/xy`` = 0, 1 along ``centroid``'s columns), ``snapshots/snapshot`` and
    ``snapshots/alpha`` along the rows and columns of every field, t and shift -- what netCDF
    readers (xarray's h5netcdf engine, ncdump) take as dimensions. The rows are preallocated
    (NaN beyond what was computed), so the scales are indices, never t: a coordinate holds no
    missing values (CF). Static metadata, written with the layout; older files lack them or have t
    as the scale, and read the same.
    """
    name_records(ts, snap)
    for group, name, rows, long_name in ((ts, "sample", ts["t"].shape[0], "index of the sample"),
                                         (snap, "snapshot", snap["t"].shape[0], "index of the snapshot")):
        group.create_dataset(name, data=np.arange(rows, dtype=np.int64))
        group[name].attrs.update(long_name=long_name, units="1")
        group[name].make_scale(name)
    for name in SERIES:
        ts[name].dims[0].attach_scale(ts["sample"])
    ts.create_dataset("xy", data=np.arange(2, dtype=np.int64))
    ts["xy"].attrs["long_name"] = "component: 0 = x, 1 = y"
    ts["xy"].make_scale("xy")
    ts["centroid"].dims[1].attach_scale(ts["xy"])
    snap["alpha"].make_scale("alpha")
    for name in ("t", "shift") + SNAPSHOT_FIELDS:
        snap[name].dims[0].attach_scale(snap["snapshot"])
    for name in SNAPSHOT_FIELDS:
        snap[name].dims[1].attach_scale(snap["alpha"])


class GroupPlace:
    """Where a case laid out in an HDF5 group of its own keeps its datasets: the file's root (``hpcves
    run``) or ``cases/<id>`` (campaign format 1). Each dataset is the case's whole array."""

    prefix = ()

    def __init__(self, group):
        self.group = group
        self.attrs = group.attrs
        self.where = group.name
        self.filename = group.file.filename
        #: low-level ids of the datasets the writer writes (CaseStore._id), and its plans (CaseStore._plan)
        self.ids, self.plans = {}, {}

    def has(self, path: str) -> bool:
        return path in self.group

    def open(self, path: str):
        return h5py.h5d.open(self.group.id, path.encode())

    def column(self, path: str) -> Column | None:
        """Each record is a dataset of its own here."""
        return None


class CaseRecord(Protocol):
    """What a run reads and writes of its case (runner.run): :class:`CaseStore` in a file of this
    process, campaign/relay.py's ``RemoteCaseStore`` through rank 0."""

    @property
    def case(self) -> Case: ...

    @property
    def status(self) -> "Status | int": ...

    @property
    def progress(self) -> np.ndarray:
        """[t, t_end, wall seconds, steps per second]."""

    def read_checkpoint(self) -> "tuple[State, int, int] | None":
        """(state, samples, snapshots) of the newest valid checkpoint, or None."""

    def passed_over(self) -> str:
        """Why the newest checkpoint slot was passed over for the other ("" if it was not)."""

    def newest_checkpoint_slot(self) -> str | None: ...

    def timeseries(self) -> dict: ...

    def set_status(self, status: int, message: str | None = None, traceback: str | None = None) -> None: ...

    def set_progress(self, t: float, t_end: float, wall: float, steps_per_second: float) -> None: ...

    def append_samples(self, rows: list[dict]) -> None: ...

    def append_snapshots(self, snaps: list[dict]) -> None: ...

    def truncate(self, n_samples: int, n_snapshots: int) -> None: ...

    def set_decision(self, code: int, t: float, step: int) -> None: ...

    def write_checkpoint(self, state: State, flush) -> None: ...


class CaseStore:
    """Reads and writes one case where ``place`` keeps it: a :class:`GroupPlace` (an h5py Group of its
    own: ``hpcves run``'s file, a format-1 campaign's case) or a row of arrays with a case dimension
    (run/blocks.py: campaign format 2)."""

    def __init__(self, group=None, *, place=None):
        self._place = place if place is not None else GroupPlace(group)
        #: the case's own group (None where it is a row of a block)
        self.group = getattr(self._place, "group", None)
        self.attrs = self._place.attrs
        self.where = self._place.where
        self.version = int(self.attrs.get("format_version", FORMAT_VERSION))
        self._arrays = _ARRAYS.get(self.version, State.ARRAYS)
        self._scalars = _SCALAR_LAYOUTS.get(self.version, _SCALAR_LAYOUT)
        #: low-level ids of the datasets this store writes, opened at their first use (:meth:`_id`), and
        #: how it writes a set of records (:meth:`_plan`), both shared by the rows of a block
        self._ids, self._plans = self._place.ids, self._place.plans
        #: the valid rows of timeseries and snapshots as this writer last set them (:meth:`_length`)
        self._lengths = {}
        #: {record path: (BLAKE2b of its rows 0..k, k)} for the records this writer appended from row 0
        #: on: an ended case's checksums come from the bytes it wrote instead of ~30 reads (:meth:`_append`)
        self._running = {}
        #: a checkpoint slot a resume passed over (it fails its checksums): the next checkpoint goes there
        #: (:meth:`write_checkpoint`), not over the one it resumed from
        self._overwrite_first = None
        #: {record: (BLAKE2b of its rows, their count)} that the slot a resume chose builds on (format 6)
        self._resumed_rows = {}
        #: the series this case records (files written before OPTIONAL_SERIES existed lack those)
        self.series_names = tuple(n for n in SERIES if n not in OPTIONAL_SERIES or self._place.has(f"timeseries/{n}"))

    # ------------------------------------------------------------------ creation
    @classmethod
    def create(cls, group, case: Case) -> "CaseStore":
        """Lay out a new case in an empty group."""
        n_samples, n_snapshots = capacities(case)
        N = stored_N(case)
        a = group.attrs
        a["format"] = FORMAT
        a["format_version"] = FORMAT_VERSION
        a["hpcves_version"] = __version__
        a["config"] = case_to_toml(case)
        a["N"] = case.numerics.N
        a["sample_capacity"] = n_samples
        a["snapshot_capacity"] = n_snapshots
        for key, value in case.flat().items():
            a[key] = value
        group.create_dataset("status", data=np.int8(PENDING))
        group.create_dataset("message", data=np.bytes_(b""), dtype=f"S{MESSAGE_BYTES}")
        group.create_dataset("traceback", data=np.bytes_(b""), dtype=f"S{TRACEBACK_BYTES}")
        group.create_dataset("decision", data=np.array(NOT_DECIDED))
        group.create_dataset("progress", data=np.array([0.0, case.run.t_end, 0.0, 0.0]))
        ts = group.create_group("timeseries")
        ts.create_dataset("length", data=np.int64(0))
        ts.create_dataset("digest", data=np.zeros(len(SERIES), dtype=np.uint64))
        for name in SERIES:
            shape = (n_samples, 2) if name == "centroid" else (n_samples,)
            ts.create_dataset(name, shape=shape, dtype="f8", fillvalue=np.nan, dcpl=_early())
        snap = group.create_group("snapshots")
        snap.create_dataset("length", data=np.int64(0))
        snap.create_dataset("digest", data=np.zeros(len(SNAPSHOT_RECORDS), dtype=np.uint64))
        snap.create_dataset("t", shape=(n_snapshots,), dtype="f8", fillvalue=np.nan, dcpl=_early())
        snap.create_dataset("shift", shape=(n_snapshots,), dtype="f8", fillvalue=np.nan, dcpl=_early())
        for name in SNAPSHOT_FIELDS:
            snap.create_dataset(name, shape=(n_snapshots, N), dtype="f8", fillvalue=np.nan, dcpl=_early())
        snap.create_dataset("alpha", data=np.arange(N) / N)
        describe(ts, snap)
        ckpt = group.create_group("checkpoint")
        for slot in ("slot0", "slot1"):
            g = ckpt.create_group(slot)
            g.create_dataset("meta", data=np.zeros(4, dtype=np.int64))
            g.create_dataset("digest", data=np.zeros(len(State.ARRAYS) + 2, dtype=np.uint64))
            g.create_dataset("records", data=np.zeros(len(SERIES) + len(SNAPSHOT_RECORDS), dtype=np.uint64))
            for name in State.ARRAYS:
                g.create_dataset(name, shape=(N,), dtype="f8", fillvalue=np.nan, dcpl=_early())
            g.create_dataset("scalars", shape=(_N_SCALARS,), dtype="f8", fillvalue=np.nan, dcpl=_early())
        return cls(group)

    @classmethod
    def open(cls, group, where: str = "") -> "CaseStore":
        """Open an existing case, checking that it is one."""
        where = where or group.name
        if attr_text(group.attrs.get("format", "")) != FORMAT:
            raise FileFormatError(f"{where}: not an hpcves case (no format = {FORMAT!r} attribute)")
        written = group.attrs.get("format_version", -1)
        if attr_integer(written) not in READS_VERSIONS:
            raise FileFormatError(f"{where}: case format version {attr_shown(written)}, this hpcves reads "
                                  + " and ".join(map(str, READS_VERSIONS)))
        missing = [k for k in ("timeseries", "snapshots", "checkpoint", "status", "message", "progress")
                   if k not in group]
        if missing:
            raise FileFormatError(f"{where}: incomplete case, missing {', '.join(missing)}")
        return cls(group)

    # ------------------------------------------------------------------ validation
    def layout(self, case: Case) -> dict:
        """Every dataset a case holds: relative name -> (shape, numpy kind)."""
        n_samples, n_snapshots = capacities(case)
        N = stored_N(case)
        out = {"status": ((), "i"), "message": ((), "S"), "progress": ((4,), "f"),
               "timeseries/length": ((), "i"), "snapshots/length": ((), "i"),
               "snapshots/t": ((n_snapshots,), "f"), "snapshots/shift": ((n_snapshots,), "f")}
        if self._place.has("traceback"):               # absent in files written before it existed
            out["traceback"] = ((), "S")
        if self._place.has("decision"):                # likewise
            out["decision"] = ((3,), "f")
        for name in self.series_names:
            out[f"timeseries/{name}"] = ((n_samples, 2) if name == "centroid" else (n_samples,), "f")
        for name in SNAPSHOT_FIELDS:
            out[f"snapshots/{name}"] = ((n_snapshots, N), "f")
        if self.version >= DIGESTS_SINCE:
            out["timeseries/digest"] = ((len(self.series_names),), "u")
            out["snapshots/digest"] = ((len(SNAPSHOT_RECORDS),), "u")
        for slot in ("slot0", "slot1"):
            out[f"checkpoint/{slot}/meta"] = ((4,), "i")
            if self.version >= DIGESTS_SINCE:
                out[f"checkpoint/{slot}/digest"] = ((len(self._arrays) + 2,), "u")
            if self.version >= RECORDS_SINCE:
                out[f"checkpoint/{slot}/records"] = ((len(self.series_names) + len(SNAPSHOT_RECORDS),), "u")
            out[f"checkpoint/{slot}/scalars"] = ((sum(n for _, n in self._scalars),), "f")
            for name in self._arrays:
                out[f"checkpoint/{slot}/{name}"] = ((N,), "f")
        return out

    def _arrays_of(self, layout: dict) -> dict:
        """``layout`` with the records of a packed array (campaign format 3) replaced by the array: its
        case's part is a record's shape with the packed axis as wide as its records together."""
        out, packed = {}, {}
        for name, (shape, kind) in layout.items():
            column = self._place.column(name)
            if column is None:
                out[name] = (shape, kind)
                continue
            width, squeezed = packed.get(column.array, (0, None))
            packed[column.array] = (width + column.width, shape if column.squeezed else squeezed)
            out[column.array] = (column.axis, kind)
        for array, (width, shape) in packed.items():
            axis, kind = out[array]
            out[array] = (shape[:axis] + (width,) + shape[axis:], kind)
        return out

    def problems(self, expected: Case | None = None, resuming: bool = False) -> list[str]:
        """What is wrong with this case's data (empty if nothing): missing or misshapen datasets, a
        status or counters out of range, checkpoints that contradict the series, data that fail their
        checksums (format 5). Never raises.

        ``expected``: the case the file should hold (its study's); a different config is a problem.
        ``resuming``: a checkpoint slot that fails its checksums is one only when no other valid slot
        passes them (a resumed run passes over it: :meth:`read_checkpoint`).
        """
        try:
            case = self.case
        except (FileFormatError, *HDF5_ERRORS) as exc:
            return [f"its config attribute cannot be read ({_first_line(exc)})"]
        if expected is not None and case.to_dict() != expected.to_dict():
            return ["its config differs from its study's case"]
        disagree = self.parameters_disagree(case)
        if disagree:
            return disagree
        found = []
        prefix = len(self._place.prefix)
        for name, (shape, kind) in self._arrays_of(self.layout(case)).items():
            try:
                d = self._place.open(name)
                if d.shape[prefix:] != shape or d.dtype.kind != kind:
                    found.append(f"{name} has shape {d.shape[prefix:]} ({d.dtype}), expected {shape} ({kind})")
                elif any(not 0 <= i < n for i, n in zip(self._place.prefix, d.shape)):
                    found.append(f"{name} holds {d.shape[0]} cases, this one is its row {self._place.prefix[0]}")
            except HDF5_ERRORS as exc:
                found.append(f"{name} is missing or unreadable ({_first_line(exc)})")
        if found:
            return found
        try:
            schedule = clock(case)
            n_samples, n_snapshots = schedule.capacities()
            attrs = self.attrs
            if (int(attrs["sample_capacity"]), int(attrs["snapshot_capacity"]), int(attrs["N"])) != \
                    (n_samples, n_snapshots, case.numerics.N):
                found.append("its capacities or N attributes do not match its config")
            status = self.status
            if status not in STATUS_NAMES:
                found.append(f"status {status} is not a status (0 to {max(STATUS_NAMES)})")
            lengths = self.n_samples, self.n_snapshots
            for what, n, cap in (("timeseries", lengths[0], n_samples), ("snapshots", lengths[1], n_snapshots)):
                if not 0 <= n <= cap:
                    found.append(f"{what}/length = {n} lies outside [0, {cap}] (the capacity)")
            sound, failing = [], []
            for slot, meta in self._slot_meta().items():
                valid, step = int(meta[0]), int(meta[1])
                t = self._checkpoint_time(slot, step, case) if valid == 1 else math.nan
                damage = self.slot_damage(slot, records=status not in ENDED) if valid == 1 else []
                if valid == 1 and not np.array_equal(self._read(f"checkpoint/{slot}/meta"), meta):
                    continue          # a live run is rewriting this slot (it is the older one): not damage
                if valid == 1:
                    (failing if damage else sound).append(damage)
                fixed = not schedule.adaptive
                if valid not in (0, 1):
                    found.append(f"checkpoint/{slot}: validity marker {valid} is neither 0 nor 1")
                elif valid and fixed and not 0 <= step <= case.n_steps:
                    found.append(f"checkpoint/{slot}: step {step} outside [0, {case.n_steps}]")
                elif valid and not fixed and not (step >= 0 and 0 <= t <= case.run.t_end * (1 + 1e-9)):
                    found.append(f"checkpoint/{slot}: step {step} at t = {t:g}, outside [0, {case.run.t_end:g}]")
                elif valid and (int(meta[2]), int(meta[3])) not in (schedule.recorded(step, t),
                                                                    schedule.legacy().recorded(step, t)):
                    found.append(f"checkpoint/{slot}: says {int(meta[2])} samples, {int(meta[3])} snapshots "
                                 f"before step {step} (t = {t:.6g}), where the run records "
                                 f"{schedule.recorded(step, t)}")
                elif valid and fixed and t != step * case.numerics.dt:
                    found.append(f"checkpoint/{slot}: step {step} at t = {t:g}, not step * dt = "
                                 f"{step * case.numerics.dt:g}")
            code, t_decided, step_decided = self.decision
            if code not in (0, *REGIMES_BY_CODE):
                found.append(f"decision code {code} is not a regime (0 to {max(REGIMES_BY_CODE)})")
            elif code and status != FINISHED:
                found.append(f"decided ({REGIMES_BY_CODE[code]}) but {STATUS_NAMES.get(status, status)}")
            elif status == FINISHED:
                expected, before = ((schedule.recorded_through(step_decided, t_decided),
                                     schedule.legacy().recorded_through(step_decided, t_decided)) if code
                                    else (schedule.finished_counts(), schedule.legacy().finished_counts()))
                if lengths not in (expected, before):        # before: written before the coincidence fix
                    found.append(f"finished, but holds {lengths[0]} samples and {lengths[1]} snapshots of "
                                 f"{expected}" + (f" (decided at t = {t_decided:.6g})" if code else ""))
            if failing and not (resuming and sound):
                found += [f"{name} fails its checksum" for damage in failing for name in damage]
            if status in ENDED:
                found += [f"{name} fails its checksum" for name in self.data_damage()]
        except HDF5_ERRORS as exc:
            found.append(f"unreadable ({_first_line(exc)})")
        return found

    def parameters_disagree(self, case: Case) -> list[str]:
        """Where the parameter attributes of a case laid out as a group ("physics.shear_rate", ...:
        what analyze and the xarray engine read) differ from its config (what a resume runs): one of
        them was edited or damaged, and which physics the data hold is unknown. Keys an older file
        lacks are passed over; a row of a block derives its attributes from its config."""
        if self.group is None:
            return []
        found = []
        for key, value in case.flat().items():
            if key in self.attrs and not _same_value(self.attrs[key], value):
                found.append(f"its config says {key} = {value!r} but its attribute {key} = "
                             f"{attr_shown(self.attrs[key])} (edited or damaged: which physics it holds is unknown)")
        return found

    # ------------------------------------------------------------------ metadata
    @property
    def config(self) -> str:
        """The case as the TOML text it is stored as."""
        return attr_text(self.attrs["config"])

    @property
    def case(self) -> Case:
        return stored_case(self.config, self.where)

    @property
    def status(self) -> Status | int:
        """The case's :class:`Status` (a code no Status has, from a damaged file, as it is)."""
        code = int(self._read("status"))
        return Status(code) if code in Status._value2member_map_ else code

    @property
    def message(self) -> str:
        return bytes(self._read("message")[()]).decode(errors="replace")

    @property
    def traceback(self) -> str:
        if not self._place.has("traceback"):
            return ""
        return bytes(self._read("traceback")[()]).decode(errors="replace")

    @_writes
    def set_status(self, status: int, message: str | None = None, traceback: str | None = None) -> None:
        """Status, and optionally the message and traceback (written before the status); an ended
        case's data get their checksums first (:meth:`data_damage`)."""
        if status in ENDED and self.version >= DIGESTS_SINCE:
            for group, names in self._record_names():
                n = self._length(group)
                self._put(f"{group}/digest", [self._digest_of(f"{group}/{name}", n) for name in names])
        if message is not None:
            self._put("message", _clip(message, MESSAGE_BYTES))
        if traceback is not None and self._place.has("traceback"):
            self._put("traceback", _clip(traceback, TRACEBACK_BYTES))
        self._put("status", status)

    @property
    def decision(self) -> tuple[int, float, int]:
        """(regime code, t, step) of the decision that stopped the run (code 0: none; decision.py)."""
        if not self._place.has("decision"):
            return 0, math.nan, -1
        code, t, step = self._read("decision")
        return (int(code) if np.isfinite(code) else -1), float(t), (int(step) if np.isfinite(step) else -1)

    @_writes
    def set_decision(self, code: int, t: float, step: int) -> None:
        if self._place.has("decision"):
            self._put("decision", (code, t, step))

    @_writes
    def set_progress(self, t: float, t_end: float, wall: float, steps_per_second: float) -> None:
        self._put("progress", (t, t_end, wall, steps_per_second))

    @property
    def progress(self) -> np.ndarray:
        return self._read("progress")

    # ------------------------------------------------------------------ the writer's access
    def _id(self, path: str) -> tuple:
        """(low-level id, dtype, shape of the case's array) of the dataset at ``path``, opened once
        per place (a block's rows share them: run/blocks.py).

        A run writes ~40 times a case, each time ~20 datasets; through h5py's high-level objects a
        dataset costs ~0.1 ms to open and select (7x what this costs), which made rank 0 the bottleneck
        of a campaign of small cases under relay. Only the writer's own values are read through these:
        HDF5 may serve a read of an open dataset from its sieve buffer, which other processes' writes
        do not update.
        """
        found = self._ids.get(path)
        if found is None:
            dataset = self._place.open(path)
            found = self._ids[path] = (dataset, dataset.dtype, dataset.shape[len(self._place.prefix):],
                                       dataset.get_space(), _memory_type(dataset.dtype))
        return found

    def _put(self, path: str, values, start: int | None = None) -> np.ndarray:
        """Write ``values`` to the case's array at ``path``, whole or from row ``start`` on; returns
        them as written (in the dataset's dtype)."""
        column = self._place.column(path)
        dataset, dtype, shape, space, mtype = self._id(column.array if column else path)
        values = np.asarray(values, dtype=dtype, order="C")
        _, memory, space = _slab(dataset, self._place.prefix, start, None if start is None else len(values), space,
                                 shape, column)
        dataset.write(memory, space, values, mtype=mtype)
        return values

    def _put_records(self, records: dict, start: int | None = None) -> dict:
        """Write several records (path -> values, all of ``rows`` rows from ``start`` on, or whole),
        those packed into one array (campaign format 3) with one write where they fill it; returns
        {path: values as written}."""
        plan = self._plans.get(tuple(records))
        if plan is None:
            plan = self._plans[tuple(records)] = self._plan(tuple(records))
        singles, arrays = plan
        written = {path: self._put(path, records[path], start) for path in singles}
        for array, members in arrays:
            dataset, dtype, shape, space, mtype = self._id(array)
            rows = None if start is None else len(records[members[0][0]])
            count, memory, space = _slab(dataset, self._place.prefix, start, rows, space, shape)
            block = np.empty(count, dtype=dtype)
            for path, index in members:
                block[index] = written[path] = np.asarray(records[path], dtype=dtype, order="C")
            dataset.write(memory, space, block, mtype=mtype)
        return written

    def _grouped(self, paths) -> tuple[list, dict]:
        """(the records of ``paths`` that are datasets of their own, {packed array: [(record, its
        Column)]} for the others)."""
        singles, packed = [], {}
        for path in paths:
            column = self._place.column(path)
            if column is None:
                singles.append(path)
            else:
                packed.setdefault(column.array, []).append((path, column))
        return singles, packed

    def _plan(self, paths: tuple) -> tuple[list, list]:
        """How :meth:`_put_records` writes ``paths``: (the records written one by one, [(packed array,
        [(record, where in the array's rows)])] for the arrays whose every column they fill)."""
        singles, packed = self._grouped(paths)
        arrays = []
        for array, members in packed.items():
            if sum(c.width for _, c in members) == self._id(array)[2][members[0][1].axis]:
                arrays.append((array, [(path, column.index()) for path, column in members]))
            else:
                singles += [path for path, _ in members]
        return singles, arrays

    def _get(self, path: str, rows: int | None = None) -> np.ndarray:
        """The case's array at ``path`` (through the writer's id), whole or its first ``rows`` rows."""
        column = self._place.column(path)
        dataset, _, shape, space, _ = self._id(column.array if column else path)
        return _part(dataset, self._place.prefix, None if rows is None else 0, rows, space, shape, column)

    def _read(self, path: str, start: int | None = None, stop: int | None = None) -> np.ndarray:
        """The case's array at ``path``, whole or rows ``start:stop``, through a dataset opened for this
        read alone (an id kept open could serve later reads from HDF5's sieve buffer, blind to other
        processes' writes); h5py's ``Dataset`` costs ~0.1 ms to open and select, and classifying a
        case reads ~25 of them."""
        return _part(self._place.open(path), self._place.prefix, start, stop, column=self._place.column(path))

    def _read_records(self, paths, start: int | None = None, stop: int | None = None) -> dict:
        """{path: :meth:`_read` of it}, each packed array read once for all of its records."""
        singles, packed = self._grouped(paths)
        out = {path: self._read(path, start, stop) for path in singles}
        for array, members in packed.items():
            whole = _part(self._place.open(array), self._place.prefix, start, stop)
            for path, column in members:
                out[path] = np.ascontiguousarray(whole[column.index()])
        return {path: out[path] for path in paths}

    def _read_group(self, group: str, names, start: int | None = None, stop: int | None = None) -> dict:
        """{name: :meth:`_read` of ``group/name``} (:meth:`_read_records`)."""
        found = self._read_records([f"{group}/{name}" for name in names], start, stop)
        return {name: found[f"{group}/{name}"] for name in names}

    def _length(self, group: str) -> int:
        """The valid rows of ``timeseries`` or ``snapshots``, as this writer last set them."""
        if group not in self._lengths:
            self._lengths[group] = int(self._get(f"{group}/length"))
        return self._lengths[group]

    def _set_length(self, group: str, n: int) -> None:
        self._put(f"{group}/length", n)
        self._lengths[group] = n

    def _append(self, records: dict, start: int) -> None:
        """Write the rows of several records (path -> values) from row ``start`` on (:meth:`_put_records`),
        and carry each one's running checksum on where this writer wrote every row before ``start``
        (else :meth:`_digest_of` reads it back).

        The checksum is of the bytes handed to HDF5, not of a read-back: a write that stored other
        bytes is then caught by the checks, not blessed."""
        for path, values in self._put_records(records, start).items():
            hashed, rows = self._running.get(path, (None, 0))
            if start == 0:
                hashed, rows = hashlib.blake2b(digest_size=8), 0
            if hashed is not None and rows == start:
                hashed.update(values)          # C-ordered, in the dataset's dtype (little-endian): its bytes
                self._running[path] = (hashed, start + len(values))
            else:
                self._running.pop(path, None)

    def _digest_of(self, path: str, rows: int) -> int:
        """:func:`digest` of a record's first ``rows`` rows: from its running checksum where this writer
        wrote exactly those rows (:meth:`_append`), else read back."""
        hashed, written = self._running.get(path, (None, -1))
        if hashed is not None and written == rows:
            return int.from_bytes(hashed.digest(), "little")
        return digest(self._get(path, rows))

    # ------------------------------------------------------------------ series
    @property
    def n_samples(self) -> int:
        return int(self._read("timeseries/length"))

    @property
    def width(self) -> int:
        """The nodes of its snapshots (stored_N of its case)."""
        column = self._place.column("snapshots/x")
        return int(self._id(column.array if column else "snapshots/x")[2][-1])

    @property
    def n_snapshots(self) -> int:
        return int(self._read("snapshots/length"))

    @_writes
    def append_samples(self, rows: list[dict]) -> None:
        """Write rows at the end of the valid part of every series, then advance ``length``."""
        if not rows:
            return
        start = self._length("timeseries")
        self._append({f"timeseries/{name}": [row[name] for row in rows] for name in self.series_names}, start)
        self._set_length("timeseries", start + len(rows))

    @_writes
    def append_snapshots(self, snaps: list[dict]) -> None:
        """Write snapshots after the valid ones, one block per field, then advance ``length``."""
        if not snaps:
            return
        start = self._length("snapshots")
        width = self.width
        records = {f"snapshots/{name}": [snap[name] for snap in snaps] for name in ("t", "shift")}
        fields = [resample(np.stack([snap[name] for name in SNAPSHOT_FIELDS]), width) for snap in snaps]
        for i, name in enumerate(SNAPSHOT_FIELDS):   # taken at the run's N, which may be below the width
            records[f"snapshots/{name}"] = [field[i] for field in fields]
        self._append(records, start)
        self._set_length("snapshots", start + len(snaps))

    def timeseries(self) -> dict:
        """The valid part of every series (numpy arrays)."""
        return self._read_group("timeseries", self.series_names, 0, self.n_samples)

    def snapshots(self) -> dict:
        return self._read_group("snapshots", SNAPSHOT_RECORDS, 0, self.n_snapshots)

    def last_snapshots(self, names, count: int) -> dict:
        """The last ``count`` valid snapshots of the fields ``names`` (fewer if there are fewer)."""
        n = self.n_snapshots
        return self._read_group("snapshots", names, max(0, n - count), n)

    @_writes
    def truncate(self, n_samples: int, n_snapshots: int) -> None:
        """Forget samples and snapshots beyond the given counts (they will be rewritten)."""
        self._set_length("timeseries", n_samples)
        self._set_length("snapshots", n_snapshots)

    def _record_names(self) -> tuple[tuple[str, tuple], ...]:
        """(group, names) of the series, then of the snapshot records: the order of their digests."""
        return ("timeseries", tuple(self.series_names)), ("snapshots", tuple(SNAPSHOT_RECORDS))

    def _records(self) -> list[tuple[str, np.ndarray]]:
        """(name, valid part) of every series, then of every snapshot record, in the order of their digests."""
        valid = {"timeseries": self.n_samples, "snapshots": self.n_snapshots}
        return [(f"{group}/{name}", values) for group, names in self._record_names()
                for name, values in self._read_group(group, names, 0, valid[group]).items()]

    def data_damage(self) -> list[str]:
        """The series and snapshot records of an ended case whose valid part fails the checksum written
        when it ended (none in a file of a format without checksums)."""
        if self.version < DIGESTS_SINCE:
            return []
        stored = np.concatenate([self._read("timeseries/digest"), self._read("snapshots/digest")])
        return [name for (name, values), d in zip(self._records(), stored) if digest(values) != int(d)]

    # ------------------------------------------------------------------ checkpoints
    def _slot_meta(self):
        return {slot: self._read(f"checkpoint/{slot}/meta") for slot in ("slot0", "slot1")}

    def newest_checkpoint_slot(self) -> str | None:
        """The valid slot of the highest step (the writer's question: read through its ids)."""
        valid = [(meta[1], slot) for slot in ("slot0", "slot1")
                 if (meta := self._get(f"checkpoint/{slot}/meta"))[0] == 1]
        return max(valid)[1] if valid else None

    def slot_damage(self, slot: str, records: bool = True) -> list[str]:
        """The datasets of a checkpoint slot that fail their checksums (none in a format without them);
        with ``records`` (format 6), also the series and snapshot records whose rows the slot builds on
        fail the checksums it took of them."""
        return self._check_slot(slot, records)[0]

    def _check_slot(self, slot: str, records: bool = True) -> tuple[list[str], dict]:
        """(:meth:`slot_damage`, {record: (BLAKE2b of the rows the slot builds on, their count)} where
        ``records`` and the format keeps their checksums, else {})."""
        g = f"checkpoint/{slot}"
        if not self._place.has(f"{g}/digest"):
            return [], {}
        meta = self._read(f"{g}/meta")
        values = [*self._read_group(g, self._arrays).values(), self._read(f"{g}/scalars"), meta[1:]]
        names = [*self._arrays, "scalars", "meta"]
        damage = [f"{g}/{name}" for name, v, d in zip(names, values, self._read(f"{g}/digest")) if digest(v) != int(d)]
        if not records or damage or self.version < RECORDS_SINCE:
            return damage, {}
        hashes = self._row_hashes(int(meta[2]), int(meta[3]))
        if len(hashes) != len(self._read(f"{g}/records")):
            return damage + [f"{g}/records"], {}
        damage += [f"{path} (the {rows} rows {g} builds on)"
                   for (path, (hashed, rows)), stored in zip(hashes.items(), self._read(f"{g}/records"))
                   if int.from_bytes(hashed.digest(), "little") != int(stored)]
        return damage, hashes

    def _row_hashes(self, n_samples: int, n_snapshots: int) -> dict:
        """{record: (BLAKE2b of its first rows, their count)}: the first ``n_samples`` of every series,
        the first ``n_snapshots`` of every snapshot record, in the order of their digests; counts beyond
        the valid rows are read as they lie (a slot that claims them fails its checksums)."""
        counts = {"timeseries": max(0, n_samples), "snapshots": max(0, n_snapshots)}
        out = {}
        for group, names in self._record_names():
            for name, values in self._read_group(group, names, 0, counts[group]).items():
                hashed = hashlib.blake2b(digest_size=8)
                hashed.update(_digest_bytes(values))
                out[f"{group}/{name}"] = (hashed, counts[group])
        return out

    def _resumable_slot(self) -> tuple[str | None, str]:
        """(the newest valid slot that passes its checksums, a note when a newer one failed them and was
        passed over); raises when every valid slot fails them."""
        valid = sorted(((int(meta[1]), slot) for slot, meta in self._slot_meta().items() if meta[0] == 1),
                       reverse=True)
        failed = []
        for step, slot in valid:
            damage, hashes = self._check_slot(slot)
            if not damage:
                self._resumed_rows = hashes
                self._overwrite_first = failed[0][0] if failed else None
                note = "; ".join(f"checkpoint {s} (step {k}) fails its checksum ({', '.join(d)}): passed over"
                                 for s, k, d in failed)
                where = self.where if self.where != "/" else self._place.filename
                return slot, (f"{where}: {note}; resumed from {slot} (step {step})" if failed else "")
            failed.append((slot, step, [name.removeprefix(f"checkpoint/{slot}/") for name in damage]))
        if failed:
            raise FileFormatError(f"{self.where}: every checkpoint fails its checksum ("
                                  + "; ".join(f"{s}: {', '.join(d)}" for s, _, d in failed) + "): cannot resume")
        return None, ""

    def passed_over(self) -> str:
        """What :meth:`read_checkpoint` passes over: a note naming a newer slot that fails its checksums
        ("" where none does)."""
        return self._resumable_slot()[1]

    def _checkpoint_time(self, slot: str, step: int, case: Case) -> float:
        """The time of a slot's state (version 2 files did not store it: step * dt)."""
        if self.version == 2:
            return step * case.numerics.dt
        names = [name for name, width in self._scalars for _ in range(width)]
        return float(self._read(f"checkpoint/{slot}/scalars")[names.index("t")])

    @_writes
    def write_checkpoint(self, state: State, flush) -> None:
        """Write ``state`` (and the current sample counts) to the older slot, safely.

        ``flush`` makes the file durable between the phases (h5py File.flush).
        """
        slot = self._overwrite_first or ('slot1' if self.newest_checkpoint_slot() == 'slot0' else 'slot0')
        self._overwrite_first = None
        g = f"checkpoint/{slot}"
        self._put(f"{g}/meta", [0], 0)
        flush()
        faults.point("checkpoint")
        size, arrays = self.width, {}
        for name in self._arrays:
            value = getattr(state, name)
            if value is None:
                value = np.full(size, np.nan)
            elif value.size != size:               # N adapting: its N values first, then NaN
                value = np.concatenate([value, np.full(size - value.size, np.nan)])
            arrays[f"{g}/{name}"] = value
        stored = self._put_records(arrays)
        written = [stored[path] for path in arrays]
        written.append(_pack_scalars(state, self._scalars))
        self._put(f"{g}/scalars", written[-1])
        written.append(np.array((state.step, self._length("timeseries"), self._length("snapshots")), dtype=np.int64))
        self._put(f"{g}/meta", written[-1], 1)
        if self.version >= RECORDS_SINCE:         # the rows a resume from this slot keeps
            self._put(f"{g}/records", [self._digest_of(f"{group}/{name}", self._length(group))
                                       for group, names in self._record_names() for name in names])
        if self.version >= DIGESTS_SINCE:
            self._put(f"{g}/digest", [digest(v) for v in written])
        flush()
        faults.point("checkpoint")
        self._put(f"{g}/meta", [1], 0)
        flush()

    def end_fields(self) -> tuple[np.ndarray, np.ndarray]:
        """(theta_tilde, psi) of the state a finished case ended in -- its newest checkpoint, written at
        its end -- where a chain's next case starts (Outcome.end, read back)."""
        where = self.where
        if self.status != FINISHED:
            raise FileFormatError(f"{where}: {STATUS_NAMES.get(self.status, self.status)}, not finished: "
                                  "no end state to start from")
        found = self.read_checkpoint()
        t_end = float(self.progress[0])
        if found is None or found[0].t != t_end:
            raise FileFormatError(f"{where}: its end state (t = {t_end:g}) was not kept as a checkpoint "
                                  "(a file of an older hpcves)")
        return found[0].theta, found[0].psi

    def fields_at(self, time: float) -> tuple[np.ndarray, np.ndarray, float]:
        """(theta_tilde, psi, t) of the snapshot nearest ``time`` (the tangent angle from the positions:
        theta = arg dz/dalpha, unwrapped, minus 2 pi alpha -- without the two highest modes, which the
        positions are drawn without), or with ``time`` = -1 of the newest
        checkpoint (the end of a finished case): the state another case may start from."""
        where = self.where
        if time == -1.0:
            found = self.read_checkpoint()
            if found is None:
                raise FileFormatError(f"{where}: no checkpoint yet: no last state to start from")
            return found[0].theta, found[0].psi, found[0].t
        times = self._read("snapshots/t", 0, self.n_snapshots)
        if times.size == 0:
            raise FileFormatError(f"{where}: no snapshots: no state at t = {time:g} to start from")
        i = int(np.argmin(np.abs(times - time)))
        z = self._read("snapshots/x", i, i + 1)[0] + 1j * self._read("snapshots/y", i, i + 1)[0]
        alpha = Spectral(z.size, 1.0, backend="numpy")           # length 1: d/ds is d/dalpha
        theta_tilde = np.unwrap(np.angle(alpha.ds_complex(z))) - alpha.circle_angle
        theta_tilde -= 2.0 * np.pi * np.round(theta_tilde[0] / (2.0 * np.pi))
        return theta_tilde, self._read("snapshots/psi", i, i + 1)[0], float(times[i])

    def read_checkpoint(self) -> tuple[State, int, int] | None:
        """(state, n_samples, n_snapshots) from the newest valid slot that passes its checksums (a newer
        one that fails them is passed over: :meth:`passed_over` says so), or None."""
        slot, _ = self._resumable_slot()
        if slot is None:
            return None
        # the rows kept, verified: an ended case's checksums go on from them (:meth:`_append`)
        self._running.update({path: (hashed.copy(), rows) for path, (hashed, rows) in self._resumed_rows.items()})
        g = f"checkpoint/{slot}"
        meta = self._read(f"{g}/meta")
        scalars = _unpack_scalars(self._read(f"{g}/scalars"), self._scalars)
        N = int(scalars.pop("N")) if "N" in scalars else stored_N(self.case)
        arrays = {name: values[:N] for name, values in self._read_group(g, self._arrays).items()}
        step = int(meta[1])
        if self.version == 2:                 # a fixed-step run: its time and steps are implied
            dt = self.case.numerics.dt
            scalars.update(t=step * dt, dt_prev=dt if step >= 1 else math.nan, dt_prev2=dt if step >= 2 else math.nan)
        def kept(name):                       # levels n-1 exist from step 1 on, n-2 from step 2 on
            return not name.startswith("prev") or step >= (2 if name.startswith("prev2") else 1)
        kwargs = {name: (value if kept(name) else None) for name, value in {**arrays, **scalars}.items()}
        state = State(step=step, **kwargs)
        for name in ("theta", "psi"):
            if not np.all(np.isfinite(getattr(state, name))):
                raise FileFormatError(f"{self.where}: checkpoint {slot} holds non-finite {name}")
        return state, int(meta[2]), int(meta[3])


def _same_value(stored, value) -> bool:
    """Whether an attribute as h5py reads it back holds ``value`` (a parameter of Case.flat)."""
    if isinstance(value, str):
        return isinstance(stored, (str, bytes)) and attr_text(stored) == value
    if isinstance(stored, (str, bytes)):
        return False
    stored, value = np.asarray(stored), np.asarray(value)
    if stored.shape != value.shape:
        return False
    try:
        both_nan = np.isnan(stored.astype(float)) & np.isnan(value.astype(float))
    except (TypeError, ValueError):
        both_nan = False
    return bool(np.all((stored == value) | both_nan))


def digest(values) -> int:
    """The 64-bit BLAKE2b checksum of an array's bytes (as stored: float64 or int64, little-endian)."""
    return int.from_bytes(hashlib.blake2b(_digest_bytes(values), digest_size=8).digest(), "little")


def _digest_bytes(values) -> np.ndarray:
    """The array whose bytes (C order, little-endian) :func:`digest` hashes (rows hashed one batch after
    another give the digest of them all)."""
    data = np.ascontiguousarray(values)
    if data.dtype.byteorder == ">" or (data.dtype.byteorder == "=" and np.little_endian is False):
        data = data.astype(data.dtype.newbyteorder("<"))
    return data                        # hashlib reads a C-contiguous array's buffer: its bytes in C order


def _slab(dataset, prefix: tuple, start: int | None, rows: int | None, space=None, shape=None,
          column: Column | None = None) -> tuple:
    """(shape, memory space, file space) of a case's part of ``dataset`` (a low-level id): its whole
    array, or ``rows`` rows from row ``start`` on; with ``column``, of that record of a packed array
    (campaign format 3). ``prefix`` is the case's place in the dataset's leading dimensions: () where
    the dataset is the case's own, (row,) in a block (run/blocks.py); ``space``: the dataset's file
    space to select in (a writer keeps one a dataset), else a new one; ``shape``: the case's part of
    the dataset, where the caller knows it (asking HDF5 costs ~3 us)."""
    if shape is None:
        shape = dataset.shape[len(prefix):]
    if column is not None:
        shape = column.shape(shape)
    if start is None:
        count, first = shape, (0,) * len(shape)
    else:
        count, first = (rows,) + shape[1:], (start,) + (0,) * (len(shape) - 1)
    if not prefix and start is None and column is None:
        return count, h5py.h5s.ALL, h5py.h5s.ALL
    where, size = (first, count) if column is None else column.place(first, count)
    space = space or dataset.get_space()
    space.select_hyperslab(prefix + where, (1,) * len(prefix) + size)
    return count, _memory_space((1,) * len(prefix) + count), space


@functools.lru_cache(maxsize=64)
def _memory_type(dtype: np.dtype):
    """The HDF5 memory type of ``dtype``, made once: h5py makes one on every read and write that is not
    given one (~3 us, half of a small write)."""
    return h5py.h5t.py_create(dtype)


@functools.lru_cache(maxsize=1024)
def _memory_space(shape: tuple):
    """A simple dataspace of ``shape`` (all selected), made once: h5py registers each new id (~5 us),
    and a writer makes ~100 selections a tiny case."""
    return h5py.h5s.create_simple(shape)


def _part(dataset, prefix: tuple, start: int | None = None, stop: int | None = None, space=None,
          shape=None, column: Column | None = None) -> np.ndarray:
    """A case's array in ``dataset`` (a low-level id), whole or rows ``start:stop`` (clipped as a slice
    is), through one hyperslab (in ``space``, of the case's ``shape`` and of ``column``'s record, where
    given: :func:`_slab`)."""
    if shape is None:
        shape = dataset.shape[len(prefix):]
    rows = None
    if start is not None:
        start, stop, _ = slice(start, stop).indices((column.shape(shape) if column else shape)[0])
        rows = max(0, stop - start)
    count, memory, space = _slab(dataset, prefix, start, rows, space, shape, column)
    dtype = dataset.dtype
    out = np.empty(count, dtype=dtype)
    if out.size:
        dataset.read(memory, space, out, mtype=_memory_type(dtype))
    return out


def _clip(text: str, size: int) -> bytes:
    """UTF-8 bytes of ``text``, at most ``size``; a long text keeps its head and its tail."""
    data = text.encode()
    if len(data) <= size:
        return data
    marker = b"\n[...]\n"
    half = (size - len(marker)) // 2
    return data[:half] + marker + data[len(data) - half:]


def _pack_scalars(state: State, layout=_SCALAR_LAYOUT) -> np.ndarray:
    out = []
    for name, width in layout:
        value = getattr(state, name)
        if value is None:
            out.extend([np.nan] * width)
        elif width == 2:
            out.extend([complex(value).real, complex(value).imag])
        else:
            out.append(float(value))
    return np.array(out)


def _unpack_scalars(values: np.ndarray, layout=_SCALAR_LAYOUT) -> dict:
    out, i = {}, 0
    for name, width in layout:
        if width == 2:
            out[name] = complex(values[i], values[i + 1])
        else:
            out[name] = float(values[i])
        i += width
    return out
