"""Many cases as rows of arrays with a case dimension (campaign format 2; docs/file-format.md).

    blocks/<k>/   the cases of one shape -- stored N, sample and snapshot capacities (``shape``
                  attribute) -- as rows: every dataset of a case's layout (store.py) with a
                  leading case dimension, one case a chunk, every chunk allocated (and filled)
                  when the block grows; attrs format_version (of the rows' data: store.py's),
                  hpcves_version, shape;
                  case (the index row of each), sample, snapshot, alpha and xy: HDF5 dimension
                  scales along the arrays' axes, what netCDF readers (h5netcdf) take as dimensions

Campaign format 3 packs the records a run writes together into one array each (a tiny case then
takes ~35 writes instead of ~133: under ``--io relay`` rank 0 makes every write of every case):

    timeseries/series      (case, sample, quantity): every series a column (centroid two), in
                           :data:`QUANTITIES` order; ``quantity``, ``units`` and ``long_name`` along
                           the last axis name them
    snapshots/fields       (case, snapshot, field, alpha): the snapshot fields (``field``)
    checkpoint/<slot>/arrays  (case, array, alpha): the arrays of a State (``array``)

The store reads and writes each record as before, through its :class:`~hpcves.run.store.Column`
(:func:`packing`); t, shift, the lengths, digests, scalars and meta stay arrays of their own.

A case is (block, row); its parameters live in the campaign's index (its config text), not in
attributes. A stage's cases cost one resize per dataset and block, however many they are
(laying out each case as a group of ~70 objects took ~2.4 ms a case), and a writer keeps one
id per dataset for all of a block's cases (:class:`RowPlace` shares them).
"""
from __future__ import annotations

import collections.abc

import h5py
import numpy as np

from hpcves.files import faults
from hpcves.model.params import Case
from hpcves.run.diagnostics import SERIES_ATTRS, SNAPSHOT_ATTRS, SNAPSHOT_FIELDS
from hpcves.run.store import (
    _N_SCALARS,
    DIGESTS_SINCE,
    FORMAT,
    FORMAT_VERSION,
    MESSAGE_BYTES,
    NOT_DECIDED,
    RECORDS_SINCE,
    SNAPSHOT_RECORDS,
    TRACEBACK_BYTES,
    CaseStore,
    Column,
    FileFormatError,
    _early,
    attr_integer,
    capacities,
    name_records,
    series_of,
    stored_case,
    stored_N,
)
from hpcves.solver.timestepping import State
from hpcves.version import __version__

BLOCKS = "blocks"
#: the campaign format whose blocks pack their records (:func:`packing`)
PACKED_SINCE = 3


def quantities(version: int = FORMAT_VERSION) -> tuple[str, ...]:
    """The columns of timeseries/series (campaign format 3) in a block of case format ``version``."""
    return tuple(q for name in series_of(version) for q in ((f"{name}_x", f"{name}_y") if name == "centroid"
                                                            else (name,)))


#: the columns of timeseries/series in a new block
QUANTITIES = quantities()
SLOTS = ("slot0", "slot1")
#: the largest chunk of a packed array, in bytes (a case's rows split into chunks of at most this).
#: hpcves opens files without a chunk cache (store.CHUNK_CACHE_BYTES): its reads and writes go to the
#: selected bytes. Other readers (h5py, netCDF: a 1 MiB chunk cache by default) read whole chunks,
#: which then fit their cache
CHUNK_BYTES = 256 * 1024


def packing(version: int = FORMAT_VERSION) -> dict[str, Column]:
    """{record: where it lies in its packed array} of a block of campaign format 3 whose rows are of
    case format ``version``."""
    out, first = {}, 0
    for name in series_of(version):
        width = 2 if name == "centroid" else 1
        out[f"timeseries/{name}"] = Column("timeseries/series", 1, first, width, squeezed=width == 1)
        first += width
    for k, name in enumerate(SNAPSHOT_FIELDS):
        out[f"snapshots/{name}"] = Column("snapshots/fields", 1, k)
    for slot in SLOTS:
        for k, name in enumerate(State.ARRAYS):
            out[f"checkpoint/{slot}/{name}"] = Column(f"checkpoint/{slot}/arrays", 0, k)
    return out


PACKED_ARRAYS = frozenset(column.array for column in packing().values())


def block_shape(case: Case) -> tuple[int, int, int]:
    """(stored N, sample capacity, snapshot capacity): what the cases of one block share."""
    return (stored_N(case), *capacities(case))


#: the case formats of a block's rows this hpcves reads and extends (a block keeps the one it was made in)
BLOCK_VERSIONS = (DIGESTS_SINCE, RECORDS_SINCE, FORMAT_VERSION)
#: :func:`packing` of every case format a block may be of
PACKINGS = {version: packing(version) for version in BLOCK_VERSIONS}


def row_layout(shape: tuple[int, int, int], packed: bool = False, version: int = FORMAT_VERSION) -> dict:
    """Every dataset of a row: name -> (shape of one case's array, dtype, fill value); ``packed``: of
    campaign format 3 (:func:`packing`); ``version``: the case format of the block's rows."""
    N, n_samples, n_snapshots = shape
    nan, series = np.nan, series_of(version)
    out = {"status": ((), "i1", 0), "message": ((), f"S{MESSAGE_BYTES}", b""),
           "traceback": ((), f"S{TRACEBACK_BYTES}", b""), "decision": ((3,), "f8", nan),
           "progress": ((4,), "f8", nan),
           "timeseries/length": ((), "i8", 0), "timeseries/digest": ((len(series),), "u8", 0),
           "snapshots/length": ((), "i8", 0), "snapshots/digest": ((len(SNAPSHOT_RECORDS),), "u8", 0),
           "snapshots/t": ((n_snapshots,), "f8", nan), "snapshots/shift": ((n_snapshots,), "f8", nan)}
    if packed:
        out["timeseries/series"] = ((n_samples, len(quantities(version))), "f8", nan)
        out["snapshots/fields"] = ((n_snapshots, len(SNAPSHOT_FIELDS), N), "f8", nan)
    else:
        for name in series:
            out[f"timeseries/{name}"] = ((n_samples, 2) if name == "centroid" else (n_samples,), "f8", nan)
        for name in SNAPSHOT_FIELDS:
            out[f"snapshots/{name}"] = ((n_snapshots, N), "f8", nan)
    for slot in SLOTS:
        out[f"checkpoint/{slot}/meta"] = ((4,), "i8", 0)
        out[f"checkpoint/{slot}/digest"] = ((len(State.ARRAYS) + 2,), "u8", 0)
        if version >= RECORDS_SINCE:
            out[f"checkpoint/{slot}/records"] = ((len(series) + len(SNAPSHOT_RECORDS),), "u8", 0)
        out[f"checkpoint/{slot}/scalars"] = ((_N_SCALARS,), "f8", nan)
        if packed:
            out[f"checkpoint/{slot}/arrays"] = ((len(State.ARRAYS), N), "f8", nan)
        else:
            for name in State.ARRAYS:
                out[f"checkpoint/{slot}/{name}"] = ((N,), "f8", nan)
    return out


def _chunks(name: str, row: tuple) -> tuple:
    """One case a chunk; a packed array's case in chunks of at most CHUNK_BYTES (whole rows)."""
    if name not in PACKED_ARRAYS:
        return (1, *row)
    per_row = 8 * int(np.prod(row[1:]))
    return (1, max(1, min(row[0], CHUNK_BYTES // per_row)), *row[1:])


def _names(group, name: str, names, table: dict | None = None) -> None:
    """A dimension scale ``name`` of ``names`` (strings) in ``group``; with ``table`` ({name: (long_name,
    units)}), the datasets ``long_name`` and ``units`` beside it, along it."""
    text = h5py.string_dtype()
    scale = group.create_dataset(name, data=np.array(names, dtype=object), dtype=text)
    scale.make_scale(name)
    if table is not None:
        for k, what in enumerate(("long_name", "units")):
            column = group.create_dataset(what, data=np.array([table[n.rsplit("_", 1)[0] if n.startswith("centroid_")
                                                                    else n][k] for n in names], dtype=object),
                                          dtype=text)
            column.dims[0].attach_scale(scale)


def _describe(group, shape: tuple[int, int, int]) -> None:
    """``long_name`` and ``units`` of every series and snapshot field, and the dimension scales ``case``,
    ``sample``, ``snapshot``, ``alpha`` and ``xy`` attached along their axes (static: written when the
    block is made)."""
    N, n_samples, n_snapshots = shape
    case = group.create_dataset("case", shape=(0,), maxshape=(None,), chunks=(1024,), dtype="i8")
    case.attrs["long_name"] = "the case's row of the campaign's index (its id as a number)"
    scales = {"case": case,
              "sample": group.create_dataset("sample", data=np.arange(n_samples, dtype=np.int64)),
              "snapshot": group.create_dataset("snapshot", data=np.arange(n_snapshots, dtype=np.int64)),
              "alpha": group.create_dataset("alpha", data=np.arange(N) / N),
              "xy": group.create_dataset("xy", data=np.arange(2, dtype=np.int64))}
    scales["xy"].attrs["long_name"] = "component: 0 = x, 1 = y"
    scales["alpha"].attrs["long_name"] = "material label of the node (alpha = j / N)"
    for name, scale in scales.items():
        scale.make_scale(name)
    name_records(group["timeseries"], group["snapshots"])
    if "timeseries/series" in group:
        _describe_packed(group, scales)
        return
    labelled = {"status", "message", "traceback", "timeseries/length", "snapshots/length",       # (netCDF readers
                *(f"timeseries/{n}" for n in series_of(FORMAT_VERSION)),                             # refuse arrays
                *(f"snapshots/{n}" for n in SNAPSHOT_RECORDS),
                *(f"checkpoint/{s}/{n}" for s in ("slot0", "slot1") for n in State.ARRAYS)}     # with some axes
    for name in labelled:                                                                       # unnamed)
        group[name].dims[0].attach_scale(scales["case"])
    axes = {"timeseries": ("sample", "xy"), "snapshots": ("snapshot", "alpha")}
    for sub, (rows, columns) in axes.items():
        for name in series_of(FORMAT_VERSION) if sub == "timeseries" else SNAPSHOT_RECORDS:
            dataset = group[sub][name]
            dataset.dims[1].attach_scale(scales[rows])
            if dataset.ndim == 3:
                dataset.dims[2].attach_scale(scales[columns])
    for slot in ("slot0", "slot1"):
        for name in State.ARRAYS:
            group[f"checkpoint/{slot}/{name}"].dims[1].attach_scale(scales["alpha"])


def _describe_packed(group, scales: dict) -> None:
    """The dimensions of a packed block's arrays (campaign format 3), and the names of their columns."""
    _names(group["timeseries"], "quantity", QUANTITIES, SERIES_ATTRS)
    _names(group["snapshots"], "field", SNAPSHOT_FIELDS, {n: SNAPSHOT_ATTRS[n] for n in SNAPSHOT_FIELDS})
    _names(group["checkpoint"], "array", State.ARRAYS)
    scales = {**scales, "quantity": group["timeseries/quantity"], "field": group["snapshots/field"],
              "array": group["checkpoint/array"]}
    group["timeseries/series"].attrs["long_name"] = "the time series, a column a quantity (quantity, long_name, units)"
    group["snapshots/fields"].attrs["long_name"] = "the snapshot fields (field, long_name, units)"
    axes = {"timeseries/series": ("case", "sample", "quantity"),
            "snapshots/fields": ("case", "snapshot", "field", "alpha"),
            "snapshots/t": ("case", "snapshot"), "snapshots/shift": ("case", "snapshot"),
            **{name: ("case",) for name in ("status", "message", "traceback", "timeseries/length", "snapshots/length")},
            **{f"checkpoint/{slot}/arrays": ("case", "array", "alpha") for slot in SLOTS}}
    for name, dims in axes.items():
        for axis, scale in enumerate(dims):
            group[name].dims[axis].attach_scale(scales[scale])


class RowAttrs(collections.abc.Mapping):
    """What a case laid out as a group holds as attributes, for a row: the block's, the config text,
    and (parsed from it when first asked for) one entry per parameter ("physics.shear_rate", ...)."""

    def __init__(self, block_attrs: dict, config: str, where: str, extra: dict):
        self._fixed = {**block_attrs, "config": config, **extra}
        self._where = where
        self._parameters = None

    def _all(self) -> dict:
        if self._parameters is None:
            case = stored_case(self._fixed["config"], self._where)
            self._parameters = {"N": case.numerics.N, **case.flat()}
        return {**self._parameters, **self._fixed}

    def __getitem__(self, key):
        if key in self._fixed:
            return self._fixed[key]
        return self._all()[key]

    def __iter__(self):
        return iter(self._all())

    def __len__(self):
        return len(self._all())


class RowPlace:
    """Where a case of a block keeps its datasets: row ``row`` of each (store.py's CaseStore reads and
    writes its part through the prefix)."""

    group = None

    def __init__(self, block, row: int, attrs: RowAttrs, where: str, ids: dict, present: dict,
                 columns: dict | None = None, plans: dict | None = None, filename: str | None = None):
        self.block, self.prefix, self.attrs, self.where = block, (row,), attrs, where
        self.filename = filename or block.file.filename        # (h5py makes a File object to say it: ~30 us)
        #: the writer's ids and plans, shared by every row of the block (CaseStore._id, CaseStore._plan)
        self.ids, self.plans = ids, ({} if plans is None else plans)
        #: {path: whether the block holds it}, shared likewise (h5py's lookup costs ~25 us)
        self._present = present
        #: {record: its Column} in a packed block (campaign format 3), else empty
        self._columns = columns or {}

    def column(self, path: str) -> Column | None:
        return self._columns.get(path)

    def has(self, path: str) -> bool:
        column = self._columns.get(path)
        if column is not None:
            path = column.array
        found = self._present.get(path)
        if found is None:
            found = self._present[path] = path in self.block
        return found

    def open(self, path: str):
        column = self._columns.get(path)
        return h5py.h5d.open(self.block.id, (column.array if column else path).encode())


class Blocks:
    """The blocks of a campaign file (the ``blocks`` group of ``h5``)."""

    def __init__(self, h5):
        self.group = h5[BLOCKS]
        #: campaign format 3: the blocks pack their records (:func:`packing`)
        self.packed = (attr_integer(h5.attrs.get("format_version", PACKED_SINCE)) or 0) >= PACKED_SINCE
        #: per block: the attributes its rows share, and the writer's ids and plans (kept until the block
        #: grows or shrinks: they hold its file spaces)
        self._attrs, self._ids, self._plans = {}, {}, {}
        #: per block: (its group, its rows, which datasets it holds, its file name), until it grows or shrinks
        self._open = {}

    @classmethod
    def create(cls, h5) -> "Blocks":
        h5.create_group(BLOCKS)
        return cls(h5)

    def names(self) -> list[str]:
        return sorted(self.group, key=int)

    def version_of(self, block: str) -> int:
        """The case format of a block's rows."""
        return attr_integer(self.group[block].attrs.get("format_version", -1)) or -1

    def shape_of(self, block: str) -> tuple[int, ...]:
        return tuple(int(v) for v in self.group[block].attrs["shape"])

    def rows(self, block: str) -> int:
        """The rows of ``block`` (those of a half-added stage included)."""
        return int(self.group[block]["status"].shape[0])

    def add(self, cases: list[Case], first: int = 0) -> list[tuple[int, int]]:
        """Lay out ``cases`` as new rows (one process, serial HDF5): (block, row) of each, in order. The
        rows start pending, with progress (0, t_end, 0, 0) and no decision; ``first`` is the index row
        of the first case (the rows' ``case`` coordinate)."""
        by_shape = {}
        for i, case in enumerate(cases):
            by_shape.setdefault(block_shape(case), []).append(i)
        known = {self.shape_of(b): b for b in self.names()}
        out = [None] * len(cases)
        for shape, members in by_shape.items():
            block = known.get(shape)
            if block is None:
                block = self._new_block(shape)
            group = self.group[block]
            start = self.rows(block)
            stop = start + len(members)
            for name in row_layout(shape, self.packed, self.version_of(block)):
                dataset = group[name]
                dataset.resize((stop, *dataset.shape[1:]))
                faults.point("block-grown")
            group["case"].resize((stop,))
            group["case"][start:stop] = np.array([first + i for i in members], dtype=np.int64)
            group["decision"][start:stop] = np.array([NOT_DECIDED] * len(members))
            group["progress"][start:stop] = np.array([(0.0, cases[i].run.t_end, 0.0, 0.0) for i in members])
            for k, i in enumerate(members):
                out[i] = (int(block), start + k)
        self._open.clear()
        self._ids.clear()
        self._plans.clear()
        return out

    def _new_block(self, shape: tuple[int, int, int]) -> str:
        block = str(len(self.group))
        group = self.group.create_group(block)
        group.attrs["format"] = FORMAT
        group.attrs["format_version"] = FORMAT_VERSION
        group.attrs["hpcves_version"] = __version__
        group.attrs["shape"] = np.array(shape, dtype=np.int64)
        for name, (row, dtype, fill) in row_layout(shape, self.packed).items():
            # no fill value on the text rows: their default (zero bytes) is the same "", and netCDF-C
            # (netCDF4-python 1.7) crashes on a fixed-length string of 4096 bytes that has one
            fill = {} if np.dtype(dtype).kind == "S" else {"fillvalue": np.array(fill, dtype=dtype)}
            group.create_dataset(name, shape=(0, *row), maxshape=(None, *row), chunks=_chunks(name, row), dtype=dtype,
                                 dcpl=_early(), **fill)
        _describe(group, shape)
        return block

    def shrink(self, used: dict[int, int]) -> None:
        """Drop the rows beyond ``used[block]`` of every block (a half-added stage; serial access)."""
        self._open.clear()
        self._ids.clear()
        self._plans.clear()
        for block in self.names():
            keep = used.get(int(block), 0)
            group = self.group[block]
            if self.rows(block) > keep:
                for name in (*row_layout(self.shape_of(block), self.packed, self.version_of(block)), "case"):
                    if name in group:
                        dataset = group[name]
                        dataset.resize((keep, *dataset.shape[1:]))

    def store(self, block: int, row: int, config: str, where: str, extra: dict | None = None) -> CaseStore:
        """The case in row ``row`` of ``block``, whose config text is ``config`` (the campaign's index)."""
        name = str(block)
        if name not in self._attrs:
            if name not in self.group:
                raise FileFormatError(f"{where}: its block {name} is missing")
            a = self.group[name].attrs
            version = attr_integer(a.get("format_version", -1))
            shape = tuple(int(v) for v in a.get("shape", ()))
            if version not in BLOCK_VERSIONS or len(shape) != 3:
                raise FileFormatError(f"{where}: block {name} has format version {version}, shape {shape}")
            self._attrs[name] = {"format": FORMAT, "format_version": version,
                                 "hpcves_version": a.get("hpcves_version", ""),
                                 "sample_capacity": shape[1], "snapshot_capacity": shape[2]}
        if name not in self._open:
            self._open[name] = (self.group[name], self.rows(name), {}, self.group.file.filename)
        group, rows, present, filename = self._open[name]
        if not 0 <= row < rows:
            raise FileFormatError(f"{where}: row {row} lies outside block {name}'s {rows}")
        attrs = RowAttrs(self._attrs[name], config, where, extra or {})
        columns = PACKINGS[self._attrs[name]["format_version"]] if self.packed else None
        return CaseStore(place=RowPlace(group, row, attrs, where, self._ids.setdefault(name, {}), present,
                                        columns, self._plans.setdefault(name, {}), filename))


def find_case(h5, case_id: str, where: str) -> CaseStore:
    """Case ``case_id`` of an open campaign file of either layout, looked up in its index (the campaign
    layer's CampaignFile.store keeps the index read; this reads it once, for one case)."""
    if BLOCKS not in h5:
        if case_id not in h5.get("cases", {}):
            raise FileFormatError(f"{where}: has no case {case_id!r}")
        return CaseStore.open(h5["cases"][case_id], where=f"{where}:{case_id}")
    index = h5["index"]
    n = int(h5.attrs.get("n_cases", 0))
    ids = [v.decode() if isinstance(v, bytes) else str(v) for v in index["case_id"][:n]]
    if case_id not in ids:
        raise FileFormatError(f"{where}: has no case {case_id!r}")
    i = ids.index(case_id)
    config = index["config"][i]
    return Blocks(h5).store(int(index["block"][i]), int(index["row"][i]),
                            config.decode() if isinstance(config, bytes) else str(config), f"/cases/{case_id}",
                            {"case_id": case_id})
