"""Laying out many cases of one shape by copying one: a campaign's cases, ~2.9 ms each instead of ~13.

:meth:`CaseStore.create` makes ~65 datasets and ~120 attributes one HDF5 call at a time; HDF5's
object copy (``H5Ocopy``) duplicates a whole laid-out case in ~1 ms. What a copy gets wrong is put
right afterwards, so that a stamped case is the one ``CaseStore.create`` would have made:

* the dimension scales: a copy's ``DIMENSION_LIST`` and ``REFERENCE_LIST`` attributes still refer
  to the original's datasets (HDF5 copies object references verbatim within a file), so each is
  written again with references to the copy's own (the HDF5 dimension-scale convention, H5DS);
* the attributes whose values differ from the original's (its parameters, its configuration);
* ``progress``, which holds the case's t_end.

Cases share a stamp when their datasets have the same shapes (:func:`layout_key`). The original
must be pristine, laid out and never written to since: a campaign stamps the cases it adds from the
first one of each shape it lays out in the same change (campaign/file.py).
"""
from __future__ import annotations

import math

import h5py
import numpy as np

from hpcves.config import case_to_toml
from hpcves.model.params import Case
from hpcves.run.store import CaseStore, capacities, stored_N

_DIMENSION_LIST = b"DIMENSION_LIST"
_REFERENCE_LIST = b"REFERENCE_LIST"


def layout_key(case: Case) -> tuple[int, int, int]:
    """What fixes the shapes of a case's datasets: (sample rows, snapshot rows, stored width)."""
    return (*capacities(case), stored_N(case))


def _same(a, b) -> bool:
    """Two attribute values that HDF5 would store alike (NaN equals NaN here)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def case_attributes(case: Case) -> dict:
    """The attributes :meth:`CaseStore.create` gives a case that depend on the case."""
    n_samples, n_snapshots = capacities(case)
    return {"config": case_to_toml(case), "N": case.numerics.N, "sample_capacity": n_samples,
            "snapshot_capacity": n_snapshots, **case.flat()}


class CaseStamp:
    """A pristine laid-out case, and what must be rewritten in a copy of it."""

    def __init__(self, original, case: Case, attrs: dict | None = None):
        self.original = original
        self.case = case
        self.key = layout_key(case)
        #: every attribute a copy may need to change: those of the case and the caller's ``attrs``
        self.attributes = {**case_attributes(case), **(attrs or {})}
        #: (dataset, ((scale, ...) per dimension)) and (scale, [(dataset, dimension), ...]), relative names
        self.dimension_lists, self.reference_lists = [], []
        datasets = []
        original.visititems(lambda name, obj: datasets.append((name, obj)) if isinstance(obj, h5py.Dataset)
                            else None)
        # a reference is resolved to a name through the object's address: HDF5's name of an object opened
        # by reference (h5py's .name) is found by searching the whole file -- 1-10 ms a reference in a
        # file of 1000 cases, 35 s of a refinement's stages
        names = {_address(obj.id): name for name, obj in datasets}
        file_id = original.file.id

        def named(ref) -> str:
            return names[_address(h5py.h5r.dereference(ref, file_id))]

        for name, obj in datasets:
            if "DIMENSION_LIST" in obj.attrs:
                self.dimension_lists.append((name, tuple(tuple(named(r) for r in refs)
                                                         for refs in obj.attrs["DIMENSION_LIST"])))
            if "REFERENCE_LIST" in obj.attrs:
                entries = obj.attrs["REFERENCE_LIST"]
                self.reference_lists.append((name, [(named(r), int(i)) for r, i in entries], entries.dtype))

    def copy(self, parent, name: str, case: Case, attrs: dict | None = None):
        """``parent[name]``, laid out for ``case`` (same :func:`layout_key`) as a copy of the original,
        with ``attrs`` (the same keys as the original was given) set on it."""
        if layout_key(case) != self.key:
            raise ValueError(f"case of shape {layout_key(case)} stamped from one of shape {self.key}")
        h5py.h5o.copy(self.original.id, b".", parent.id, name.encode())
        group = parent[name]
        self._repoint(group)
        for key, value in {**case_attributes(case), **(attrs or {})}.items():
            if key not in self.attributes:
                group.attrs[key] = value
            elif not _same(value, self.attributes[key]):
                _set_attribute(group, key, value)
        if case.run.t_end != self.case.run.t_end:
            group["progress"][1] = case.run.t_end
        return group

    def _repoint(self, group) -> None:
        """Point the copy's dimension scales at its own datasets."""
        refs = {}

        def ref(path):
            if path not in refs:
                refs[path] = h5py.h5r.create(group.id, path.encode(), h5py.h5r.OBJECT)
            return refs[path]

        vlen = h5py.vlen_dtype(h5py.ref_dtype)
        values = {}                      # most datasets share their scales (a series: the sample times)
        for name, dims in self.dimension_lists:
            if dims not in values:
                value = values[dims] = np.empty(len(dims), dtype=vlen)
                for i, scales in enumerate(dims):
                    value[i] = np.array([ref(p) for p in scales], dtype=h5py.ref_dtype)
            _write_attribute(group, name, _DIMENSION_LIST, values[dims])
        for name, entries, dtype in self.reference_lists:
            _write_attribute(group, name, _REFERENCE_LIST, np.array([(ref(p), i) for p, i in entries], dtype=dtype))


def _address(object_id) -> int:
    """Where an HDF5 object's header lies in its file: what tells two objects apart."""
    return h5py.h5o.get_info(object_id).addr


def _write_attribute(group, name: str, attribute: bytes, value) -> None:
    """Overwrite an existing attribute of ``group[name]`` in place (same type and shape)."""
    obj = h5py.h5o.open(group.id, name.encode())     # held open: HDF5 writes an attribute of an open object
    h5py.h5a.open(obj, attribute).write(value)


def _set_attribute(group, key: str, value) -> None:
    """``group.attrs[key] = value`` for an attribute the copy has: written in place where the value has
    the stored type (a number, a text), else replaced as h5py does (deleted and created anew: ~3 times
    as long)."""
    attribute = h5py.h5a.open(group.id, key.encode())
    stored = attribute.dtype
    if attribute.shape == ():
        text = h5py.check_string_dtype(stored)
        if isinstance(value, str) and text is not None and (text.encoding, text.length) == ("utf-8", None):
            attribute.write(np.array(value, dtype=stored))
            return
        if isinstance(value, (bool, int, float)) and np.asarray(value).dtype == stored:
            attribute.write(np.asarray(value))
            return
    group.attrs[key] = value


class Stamper:
    """Lays out cases in ``parent``: the first of each shape with :meth:`CaseStore.create`, the rest
    stamped from it."""

    def __init__(self, parent):
        self.parent = parent
        self.stamps: dict[tuple, CaseStamp] = {}

    def lay_out(self, name: str, case: Case, attrs: dict | None = None):
        """``parent[name]`` laid out for ``case``, with ``attrs`` set on it; returns the group."""
        stamp = self.stamps.get(layout_key(case))
        if stamp is not None:
            return stamp.copy(self.parent, name, case, attrs)
        group = self.parent.create_group(name)
        CaseStore.create(group, case)
        for key, value in (attrs or {}).items():
            group.attrs[key] = value
        self.stamps[layout_key(case)] = CaseStamp(group, case, attrs)
        return group
