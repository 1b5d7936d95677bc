"""The series and snapshots of a case: how a writer reaches its datasets (low-level ids, packed
records written at once), appends rows with running checksums, and reads them back -- the part of
:class:`hpcves.run.store.CaseStore` that holds the records."""
from __future__ import annotations

import hashlib

import numpy as np

from hpcves.numerics.spectral import resample
from hpcves.run.checksums import digest
from hpcves.run.diagnostics import SNAPSHOT_FIELDS
from hpcves.run.h5files import _writes
from hpcves.run.hyperslabs import _memory_type, _part, _slab
from hpcves.run.layout import DIGESTS_SINCE, SNAPSHOT_RECORDS


class CaseRecords:
    """The records of a case (a mixin of :class:`hpcves.run.store.CaseStore`, whose ``__init__`` sets the
    place, the ids and the writer's lengths and running checksums it uses)."""

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
