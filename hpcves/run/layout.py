"""What a case file holds and how it is laid out: the format and its versions, the statuses, a
checkpoint's scalars and arrays per version, the datasets of a new case (:func:`create_layout`, the
layout run/store.py's docstring gives), their sizes, their netCDF names and dimension scales, the
places a case lives in, and the interface a run writes through (:class:`CaseRecord`)."""
from __future__ import annotations

import enum
import math
from typing import Protocol

import h5py
import numpy as np

from hpcves.config import case_from_toml, case_to_toml
from hpcves.errors import FileFormatError
from hpcves.files.atomic import METADATA_BYTES_PER_CASE
from hpcves.model.params import Case, ConfigError
from hpcves.run.diagnostics import RHEOLOGY_SERIES, SERIES, SERIES_ATTRS, SNAPSHOT_ATTRS, SNAPSHOT_FIELDS
from hpcves.run.h5files import attr_text
from hpcves.run.hyperslabs import Column
from hpcves.run.schedule import clock
from hpcves.solver.timestepping import State
from hpcves.version import __version__

FORMAT = "hpcves-case"
FORMAT_VERSION = 7                  # 7: the rheology series; 6: a checkpoint's checksums of the rows it
                                    # builds on; 5: checksums of the checkpoints and of an ended case's data
READS_VERSIONS = (2, 3, 4, 5, 6, 7)  # 4: checkpoints hold their N (N adapting) and the resize memory; 3: t,
                                    # the step controller and level n-2; 2: fixed-step checkpoints
                                    # (t = step dt); 1 held psi at material labels
#: the first format whose cases carry checksums
DIGESTS_SINCE = 5
#: the first format whose checkpoints carry the checksums of the series and snapshots they build on
RECORDS_SINCE = 6
#: the first format whose cases record the rheology series (diagnostics.RHEOLOGY_SERIES)
RHEOLOGY_SINCE = 7
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
_SCALAR_LAYOUTS[5] = _SCALAR_LAYOUTS[6] = _SCALAR_LAYOUTS[7] = _SCALAR_LAYOUTS[4]
_ARRAYS = {2: State.ARRAYS[:6], 3: State.ARRAYS, 4: State.ARRAYS, 5: State.ARRAYS, 6: State.ARRAYS, 7: State.ARRAYS}
assert _ARRAYS[2] == ("theta", "psi", "prev_theta", "prev_psi", "prev_rate_theta", "prev_rate_psi")
_SCALAR_LAYOUT = _SCALAR_LAYOUTS[FORMAT_VERSION]
#: the per-snapshot records, in the order of snapshots/digest
SNAPSHOT_RECORDS = ("t", "shift") + SNAPSHOT_FIELDS
_N_SCALARS = sum(n for _, n in _SCALAR_LAYOUT)


def series_of(version: int) -> tuple[str, ...]:
    """The series a case of format ``version`` may record (a group's case made before a series existed
    lacks it; store.CaseStore.series_names): a block's packed columns are these."""
    return SERIES if version >= RHEOLOGY_SINCE else tuple(n for n in SERIES if n not in RHEOLOGY_SERIES)


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


def create_layout(group, case: Case) -> None:
    """Lay out a new case in an empty group: its attributes and every dataset, preallocated (the
    module's docstring in run/store.py gives the layout)."""
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
