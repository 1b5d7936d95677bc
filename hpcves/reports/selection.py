"""Finding cases of a campaign Dataset by their physics: ``ds.sel(shear_rate=40, psi_bar=0.3)``, and
one case on its own time axis, ``ds.hpcves.case(shear_rate=40, psi_bar=0.3)``.

The cases of a campaign are labelled by their ids (``case``, a dimension coordinate); their
parameters are coordinates along ``case``. xarray selects by a non-dimension coordinate only
through an index on it, and one index per dimension: a pandas MultiIndex would replace the case ids
and cannot be written to netCDF. :class:`CaseParameters` is a custom xarray index
(https://docs.xarray.dev/en/stable/internals/how-to-create-custom-index.html) over all the
parameter coordinates together that leaves ``case`` and every variable as they are.
"""
from __future__ import annotations

import numpy as np
import xarray as xr
from xarray.core.indexing import IndexSelResult

#: relative tolerance of a parameter match: a value as the tables print it (6 significant digits, %g)
#: selects its case; a campaign's values lie much further apart than that
MATCH_RTOL = 1e-5


def _close(values: np.ndarray, label: float) -> np.ndarray:
    return np.isclose(values, label, rtol=MATCH_RTOL, atol=MATCH_RTOL * 1e-3)


def _listed(values: np.ndarray) -> str:
    unique = np.unique(values[np.isfinite(values)])
    shown = ", ".join(f"{v:g}" for v in unique[:8])
    return shown + (f", ... ({unique.size} values)" if unique.size > 8 else "")


class CaseParameters(xr.Index):
    """An index over the parameter coordinates of a campaign's cases (all along one dimension).

    ``sel`` takes any of them: a number (the cases with that value; ``method="nearest"``: with the
    value nearest it), a list of numbers, or a slice (a closed range). Naming every parameter that
    varies among the cases with numbers selects one case and drops the dimension, as a case id does;
    anything else keeps the dimension, with the cases that match.
    """

    def __init__(self, values: dict, dim: str):
        self.values = {name: np.asarray(v, dtype=float) for name, v in values.items()}
        self.dim = dim

    @classmethod
    def from_variables(cls, variables, *, options):
        dims = {var.dims for var in variables.values()}
        if len(dims) != 1 or len(next(iter(dims))) != 1:
            raise ValueError("CaseParameters: the coordinates must lie along one and the same dimension")
        return cls({name: var.values for name, var in variables.items()}, next(iter(dims))[0])

    def _varying(self) -> set:
        return {name for name, v in self.values.items() if np.unique(v).size > 1}

    def sel(self, labels, method=None, tolerance=None):
        mask = np.ones(next(iter(self.values.values())).shape, dtype=bool)
        scalars = set()
        for name, label in labels.items():
            values = self.values[name]
            if isinstance(label, slice):
                if label.step is not None:
                    raise ValueError(f"sel({name}=slice(...)): a range of values takes no step")
                low = -np.inf if label.start is None else label.start
                high = np.inf if label.stop is None else label.stop
                mask &= (values >= low) & (values <= high)
                continue
            wanted = np.atleast_1d(np.asarray(label, dtype=float))
            if method == "nearest":
                unique = np.unique(values)
                wanted = unique[np.abs(unique[None, :] - wanted[:, None]).argmin(axis=1)]
                if tolerance is not None and np.any(np.abs(wanted - np.atleast_1d(label)) > tolerance):
                    raise KeyError(f"no case with {name} within {tolerance:g} of {label} (the cases have "
                                   f"{name} = {_listed(values)})")
            elif method is not None:
                raise ValueError(f"sel(..., method={method!r}): the cases' parameters take method='nearest' or none")
            hits = np.zeros_like(mask)
            for value in wanted:
                found = _close(values, value)
                if not found.any():
                    raise KeyError(f"no case with {name} = {value:g} (the cases have {name} = {_listed(values)})")
                hits |= found
            mask &= hits
            if np.ndim(label) == 0:
                scalars.add(name)
        where = np.flatnonzero(mask)
        if where.size == 0:
            asked = ", ".join(f"{k} = {v}" for k, v in labels.items())
            raise KeyError(f"no case has {asked} together")
        if where.size == 1 and self._varying() <= scalars:
            return IndexSelResult({self.dim: int(where[0])})
        return IndexSelResult({self.dim: where})

    def isel(self, indexers):
        key = indexers.get(self.dim)
        if key is None:
            return self
        if isinstance(key, xr.Variable):
            key = key.values
        if np.ndim(key) == 0 and not isinstance(key, slice):
            return None                          # the dimension is gone, and the index with it
        return type(self)({name: v[key] for name, v in self.values.items()}, self.dim)

    def create_variables(self, variables=None) -> dict:
        """The coordinates this index holds (with the attributes of ``variables`` where given)."""
        variables = variables or {}
        return {name: xr.Variable(self.dim, v, variables[name].attrs if name in variables else None)
                for name, v in self.values.items()}

    def equals(self, other, **kwargs) -> bool:
        return (isinstance(other, CaseParameters) and other.dim == self.dim
                and other.values.keys() == self.values.keys()
                and all(np.array_equal(v, other.values[k], equal_nan=True) for k, v in self.values.items()))

    def _repr_inline_(self, max_width=None) -> str:
        return "CaseParameters"


def with_parameter_index(ds: xr.Dataset, names) -> xr.Dataset:
    """``ds`` with a :class:`CaseParameters` index over the coordinates ``names`` (those it has)."""
    names = [n for n in names if n in ds.coords]
    return ds.set_xindex(names, CaseParameters) if names else ds


@xr.register_dataset_accessor("hpcves")
class CampaignAccessor:
    """``ds.hpcves``: what a campaign Dataset (hpcves.open_campaign) adds to xarray's own methods."""

    def __init__(self, ds: xr.Dataset):
        self._ds = ds

    def case(self, case: str | None = None, **parameters) -> xr.Dataset:
        """One case -- by id (``"0003"``) or by its parameters (``shear_rate=40, psi_bar=0.3``) -- over its own
        time axis: the samples it computed, with ``time`` (its t) the dimension, as ``hpcves.open_case``
        gives it, so that ``.theta.plot()`` draws theta against t."""
        ds = self._ds
        if "case" not in ds.dims:
            raise ValueError("ds.hpcves.case(...): not a Dataset over cases (open_campaign gives one)")
        if (case is None) == (not parameters):
            raise TypeError("ds.hpcves.case(...): give a case id or parameters (shear_rate=..., ...), not both")
        one = ds.sel(case=case) if case is not None else ds.sel(**parameters)
        if "case" in one.dims:
            ids = ", ".join(str(c) for c in one["case"].values[:8])
            raise KeyError(f"{one.sizes['case']} cases have {', '.join(f'{k} = {v}' for k, v in parameters.items())} "
                           f"({ids}): name more parameters, or a case id")
        if "t" not in one:
            return one
        computed = int(np.isfinite(one["t"].values).sum())
        one = one.isel(sample=slice(0, computed))
        time = one["t"].values
        one = one.drop_vars(["t", "sample"]).rename_dims(sample="time")
        return one.assign_coords(time=("time", time, {**ds["t"].attrs, "axis": "T"}))
