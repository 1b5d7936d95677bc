"""Reading and writing a case's part of a dataset through one HDF5 hyperslab: the whole array of a
case laid out as a group, its row of a block (campaign format 2, run/blocks.py), or one record of a
packed array (format 3: :class:`Column`), with the low-level ids and spaces a writer keeps."""
from __future__ import annotations

import functools
from dataclasses import dataclass

import h5py
import numpy as np


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
