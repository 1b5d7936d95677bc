"""A stamped case (copied from one laid out, then put right) is the case CaseStore.create makes."""
from __future__ import annotations

import dataclasses

import h5py
import numpy as np
import pytest

from hpcves.config import case_from_toml
from hpcves.run.stamp import CaseStamp, Stamper, layout_key
from hpcves.run.store import CaseStore

BASE = """
[physics]
shear_rate = 2.0
[numerics]
N = 16
dt = 1e-3
[run]
t_end = 0.05
sample_interval = 0.01
snapshot_interval = 0.02
checkpoint_interval = 0.02
"""


def case(**changes):
    c = case_from_toml(BASE)
    for group, values in changes.items():
        c = dataclasses.replace(c, **{group: dataclasses.replace(getattr(c, group), **values)})
    return c


def tree(group) -> dict:
    """Everything in a group: each object's kind, shape, dtype, bytes and attributes, with object
    references given as the names (relative to ``group``) of what they point to."""
    file, base = group.file, group.name.rstrip("/") + "/"

    def shown(value):
        if isinstance(value, h5py.Reference):
            return "-> " + file[value].name[len(base):]
        if isinstance(value, np.ndarray) and value.dtype.names:
            return [tuple(shown(v) for v in row) for row in value.tolist()]
        if isinstance(value, np.ndarray) and value.dtype == object:
            return [shown(v) for v in value]
        if isinstance(value, (list, tuple)):
            return [shown(v) for v in value]
        if isinstance(value, np.ndarray):
            return (value.dtype.str, value.shape, value.tobytes())
        return (type(value).__name__, value if value == value else "nan")

    out = {}

    def visit(name, obj):
        attrs = {k: shown(obj.attrs[k]) for k in obj.attrs}
        if isinstance(obj, h5py.Dataset):
            out[name] = ("dataset", obj.shape, obj.dtype.str, obj[()].tobytes() if obj.shape != () else obj[()],
                         attrs)
        else:
            out[name] = ("group", attrs)

    visit(".", group)
    group.visititems(visit)
    return out


CASES = [case(physics={"shear_rate": s}) for s in (2.0, 3.5, 7.25)] + [
    case(physics={"shear_rate": 1.0, "psi_bar": 0.3}),
    case(run={"t_end": 0.055}),                                # the same shapes, another t_end (progress)
    case(run={"t_end": 0.06}),                                 # more rows
    case(numerics={"N": 32}),                                  # another width
    case(physics={"bending_law": "linear"}),                   # a string parameter
]


def test_every_stamped_case_is_the_case_create_makes(tmp_path):
    with h5py.File(tmp_path / "made.h5", "w") as made, h5py.File(tmp_path / "stamped.h5", "w") as stamped:
        stamper = Stamper(stamped.create_group("cases"))
        for i, c in enumerate(CASES):
            name = f"{i:04d}"
            group = made.create_group("cases").create_group(name) if i == 0 else made["cases"].create_group(name)
            CaseStore.create(group, c)
            group.attrs["case_id"] = name
            stamper.lay_out(name, c, {"case_id": name})
        assert len(stamper.stamps) == len({layout_key(c) for c in CASES}) < len(CASES)
        for i in range(len(CASES)):
            name = f"cases/{i:04d}"
            assert tree(stamped[name]) == tree(made[name]), name
            # the scales are attached to the copy's own datasets, as HDF5's dimension-scale API sees it
            ts = stamped[name]["timeseries"]
            assert h5py.h5ds.is_attached(ts["theta"].id, ts["sample"].id, 0)
            assert h5py.h5ds.is_attached(ts["t"].id, ts["sample"].id, 0)
            assert stamped[name]["snapshots/psi"].dims[1][0].name == f"/{name}/snapshots/alpha"


def test_a_case_of_another_shape_is_not_stamped(tmp_path):
    with h5py.File(tmp_path / "f.h5", "w") as h5:
        group = h5.create_group("a")
        CaseStore.create(group, CASES[0])
        stamp = CaseStamp(group, CASES[0])
        with pytest.raises(ValueError, match="shape"):
            stamp.copy(h5, "b", case(numerics={"N": 32}))
