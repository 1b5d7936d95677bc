"""Case and campaign files as xarray Datasets (``hpcves.open_case``, ``hpcves.open_campaign``).

The files preallocate every sample and snapshot (docs/file-format.md), so the raw datasets hold
NaN rows beyond what was computed; these readers cut every case to its ``length`` counters, name
the dimensions, carry the ``long_name`` / ``units`` attributes, and put the physics parameters
(and, for a campaign, each case's regime from the file's ``analysis/`` group) beside the data.
Read without locking, like ``hpcves analyze``: a file a campaign is writing is always whole.
Everything is read into memory (no dask here): a campaign's Dataset takes
cases x longest run x series x 8 bytes -- pass ``variables`` to read fewer series.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from hpcves.campaign.file import FORMAT as CAMPAIGN_FORMAT
from hpcves.campaign.file import CampaignFile
from hpcves.run.diagnostics import SERIES_ATTRS, SNAPSHOT_ATTRS, SNAPSHOT_FIELDS
from hpcves.run.store import FORMAT as CASE_FORMAT
from hpcves.run.store import HDF5_ERRORS, STATUS_NAMES, CaseStore, FileFormatError, attr_text, open_file, reading
from hpcves.run.verdict import PARAMETERS
from hpcves.model.params import ADDED_LATER, parameter_of

#: analysis/ columns carried per case by open_campaign (the rest are in regimes.csv)
RESULTS = ("regime", "period", "period_err", "period_dt_err", "period_N_err", "theta_mean", "theta_mean_err",
           "theta_mean_dt_err", "theta_mean_N_err", "t_settle", "cycles", "bending_gap", "reason")


def _attrs(table: dict, name: str) -> dict:
    long_name, units = table.get(name, (name, "1"))
    return {"long_name": long_name, "units": units}


def _case_variables(store: CaseStore, names, snapshots: bool, sample_dim: str) -> dict:
    """{name: (dims, values, attrs)} of one case, cut to what was computed."""
    out = {}
    series = store.timeseries()
    for name in names:
        if name in series and name != "t":
            dims = (sample_dim, "xy") if name == "centroid" else (sample_dim,)
            out[name] = (dims, series[name], _attrs(SERIES_ATTRS, name))
    out["t"] = ((sample_dim,), series["t"], _attrs(SERIES_ATTRS, "t"))
    if snapshots:
        snap = store.snapshots()
        out["snapshot_t"] = (("snapshot",), snap["t"], _attrs(SNAPSHOT_ATTRS, "t"))
        out["shift"] = (("snapshot",), snap["shift"], _attrs(SNAPSHOT_ATTRS, "shift"))
        for name in SNAPSHOT_FIELDS:
            out[name] = (("snapshot", "alpha"), snap[name], _attrs(SNAPSHOT_ATTRS, name))
    return out


def _check_names(names, store: CaseStore) -> tuple:
    if names is None:
        return store.series_names
    unknown = [n for n in names if n not in store.series_names]
    if unknown:
        raise FileFormatError(f"variables: no series {', '.join(unknown)} (there are "
                              f"{', '.join(store.series_names)})")
    return tuple(names)


def open_case(path, case: str | None = None, *, variables=None, snapshots: bool = True):
    """One case as an xarray Dataset: the series over ``t`` (dimension ``time``; ``centroid`` over
    (time, xy)), with ``snapshots`` the snapshot fields over (snapshot, alpha), the four physics
    parameters as scalar coordinates and the whole config, status and message as attributes.

    ``path``: the file of ``hpcves run``, or a campaign file with ``case`` its id ("0003");
    ``variables``: the series to read (default: all)."""
    import xarray as xr

    path = Path(path)
    with open_file(path, "r", locking=False) as h5, reading(str(path)):
        kind = attr_text(h5.attrs.get("format", ""))
        if kind == CAMPAIGN_FORMAT:
            campaign = CampaignFile.check(h5, str(path))
            ids = campaign.case_ids
            if case is None or case not in ids:
                listed = ", ".join(ids[:5]) + (", ..." if len(ids) > 5 else "")
                raise FileFormatError(f"{path}: a campaign file; name the case, e.g. open_case(path, "
                                      f"{ids[0]!r}) (cases: {listed})" if case is None else
                                      f"{path}: no case {case!r} (cases: {listed})")
            store = campaign.store(case)
        elif kind == CASE_FORMAT:
            if case is not None:
                raise FileFormatError(f"{path}: the file of one run; it has no case {case!r}")
            store = CaseStore.open(h5, where=f"{path}:/")
        else:
            raise FileFormatError(f"{path}: not an hpcves campaign or run file (no format attribute)")
        names = _check_names(variables, store)
        data = _case_variables(store, names, snapshots, "time")
        attrs = {k: (attr_text(v) if isinstance(v, bytes) else v) for k, v in store.attrs.items()
                 if not k.startswith("physics.") or k.removeprefix("physics.") not in PARAMETERS}
        attrs.update(status=STATUS_NAMES.get(store.status, str(store.status)), message=store.message,
                     t_reached=float(store.progress[0]), source=str(path))
        physics = {k: float(parameter_of(store.attrs, k, "physics.")) for k in PARAMETERS}
        N = store.width
    t = data.pop("t")
    coords = {"time": t[1], "xy": ["x", "y"], **physics}
    if snapshots:
        coords["snapshot"] = data.pop("snapshot_t")[1]
        coords["alpha"] = np.arange(N) / N
    ds = xr.Dataset({k: xr.Variable(*v) for k, v in data.items()}, coords=coords, attrs=attrs)
    ds["time"].attrs.update(t[2])
    if snapshots:
        ds["snapshot"].attrs.update(_attrs(SNAPSHOT_ATTRS, "t"))
        ds["alpha"].attrs.update(_attrs(SNAPSHOT_ATTRS, "alpha"))
    for k in PARAMETERS:
        ds[k].attrs["long_name"] = k.replace("_", " ")
    return ds


def open_campaign(path, *, variables=None):
    """Every case of a campaign file as one xarray Dataset over (case, sample): each case's series
    from its first sample to its last computed one, NaN beyond (cases differ in length and in
    sampling, so the time is the 2-D coordinate ``t`` (case, sample), not a shared axis); the swept
    parameters, status and search index as coordinates along ``case``; and, where the file was
    analysed (``hpcves analyze``), each case's regime, period, mean inclination and their error bars.

    ``variables``: the series to read (default: all). A case whose data cannot be read comes back
    with status "damaged" and NaN series."""
    import xarray as xr

    path = Path(path)
    with open_file(path, "r", locking=False) as h5, reading(str(path)):
        if attr_text(h5.attrs.get("format", "")) != CAMPAIGN_FORMAT:
            raise FileFormatError(f"{path}: not a campaign file (open the file of one run with open_case)")
        campaign = CampaignFile.check(h5, str(path))
        ids = list(campaign.case_ids)
        cases, statuses, parameters = [], [], {k: [] for k in PARAMETERS}
        names = None
        for i, case_id in enumerate(ids):
            try:
                store = campaign.store(case_id)
                if store.problems():
                    raise FileFormatError(case_id)
            except (FileFormatError, *HDF5_ERRORS):
                cases.append(None)
                statuses.append("damaged")
                for k in PARAMETERS:
                    parameters[k].append(float(h5["index"][k][i]) if k in h5["index"] else ADDED_LATER.get(k, np.nan))
                continue
            names = names or _check_names(variables, store)
            cases.append(_case_variables(store, names, False, "sample"))
            statuses.append(STATUS_NAMES.get(store.status, str(store.status)))
            for k in PARAMETERS:
                parameters[k].append(float(parameter_of(store.attrs, k, "physics.")))
        searches = np.asarray(h5["index"]["search"][:]) if "search" in h5["index"] else np.full(len(ids), -1)
        results = {}
        if "analysis" in h5 and "case" in h5["analysis"]:
            group = h5["analysis"]
            analysed = [attr_text(c) for c in group["case"][:]]
            if analysed == ids:
                for column in RESULTS:
                    if column in group:
                        values = group[column][:]
                        results[column] = ([attr_text(v) for v in values] if values.dtype.kind in "OS"
                                           else np.asarray(values, dtype=float))
        attrs = {"name": campaign.name, "mode": campaign.mode, "sweep_keys": ",".join(campaign.sweep_keys),
                 "campaign_toml": attr_text(h5.attrs.get("campaign_toml", "")), "source": str(path)}
    names = names or ()
    longest = max((len(c["t"][1]) for c in cases if c is not None), default=0)
    data = {}
    for name in ("t",) + tuple(n for n in names if n != "t"):
        template = next((c[name] for c in cases if c is not None), None)
        if template is None:
            continue
        dims, _, var_attrs = template
        shape = (len(ids), longest) + ((2,) if name == "centroid" else ())
        values = np.full(shape, np.nan)
        for i, c in enumerate(cases):
            if c is not None:
                values[i, : len(c[name][1])] = c[name][1]
        data[name] = xr.Variable(("case",) + dims, values, var_attrs)
    coords = {"case": ids, "status": ("case", statuses), "search": ("case", searches),
              **{k: ("case", np.asarray(v)) for k, v in parameters.items()}}
    if "centroid" in data:
        coords["xy"] = ["x", "y"]
    t = data.pop("t", None)
    if t is not None:
        coords["t"] = t
    ds = xr.Dataset(data, coords=coords, attrs=attrs)
    for column, values in results.items():
        ds[column] = ("case", values)
    return ds
