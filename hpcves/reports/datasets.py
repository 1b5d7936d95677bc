"""Case and campaign files as xarray Datasets (``hpcves.open_case``, ``hpcves.open_campaign``).

The files preallocate every sample and snapshot (docs/file-format.md), so the raw datasets hold
NaN rows beyond what was computed; these readers cut every case to its ``length`` counters, name
the dimensions, carry the ``long_name`` / ``units`` attributes, and put the physics parameters
(and, for a campaign, each case's regime from the file's ``analysis/`` group) beside the data.
Read without locking, like ``hpcves analyze``: a file a campaign is writing is always whole.
Everything is read into memory (no dask here): a campaign's Dataset takes
cases x longest run x series x 8 bytes -- pass ``variables`` to read fewer series.

Both follow CF-1.11 (reports/conventions.py): units and long_name on every variable, flags for the
categorical results, attribute names without dots; ``open_campaign(path, tree=True)`` gives the
file as an xarray DataTree (cases, analysis, and the refinement or search a file records), and
reports/backend.py makes both ``xarray.open_dataset(path, engine="hpcves")``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from hpcves.campaign.file import FORMAT as CAMPAIGN_FORMAT
from hpcves.campaign.file import CampaignFile
from hpcves.model.params import ADDED_LATER, parameter_of
from hpcves.reports.conventions import (
    CONVENTIONS,
    SERIES_NAMES,
    SNAPSHOT_NAMES,
    described,
    netcdf_attrs,
    parameter_attrs,
    regime_flag,
    result_attrs,
    status_flag,
)
from hpcves.run.diagnostics import SERIES_ATTRS, SNAPSHOT_ATTRS, SNAPSHOT_FIELDS
from hpcves.run.store import FORMAT as CASE_FORMAT
from hpcves.run.store import HDF5_ERRORS, STATUS_NAMES, CaseStore, FileFormatError, attr_text, open_file, reading
from hpcves.run.verdict import PARAMETERS, STRESS_SERIES

#: analysis/ columns carried per case by open_campaign (the rest are in regimes.csv)
RESULTS = ("regime", "period", "period_err", "period_dt_err", "period_N_err", "theta_mean", "theta_mean_err",
           "theta_mean_dt_err", "theta_mean_N_err", "t_settle", "cycles", "bending_gap",
           *(f"{name}{part}" for name in STRESS_SERIES for part in ("", "_err", "_dt_err", "_N_err")), "reason")


def _attrs(table: dict, name: str) -> dict:
    """CF attributes of a series (``table`` SERIES_ATTRS) or a snapshot field (SNAPSHOT_ATTRS)."""
    description, units = table.get(name, (name, "1"))
    short = (SERIES_NAMES if table is SERIES_ATTRS else SNAPSHOT_NAMES).get(name)
    return described(description, units, short)


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
        problems = store.problems()
        if problems:                          # as analyze: values that fail their checks are not handed out
            raise FileFormatError(f"{path}{f' case {case}' if case else ''}: damaged, not read ("
                                  + "; ".join(problems[:3]) + (f"; {len(problems) - 3} more" if len(problems) > 3
                                                               else "") + ")")
        names = _check_names(variables, store)
        data = _case_variables(store, names, snapshots, "time")
        attrs = {k: (attr_text(v) if isinstance(v, bytes) else v) for k, v in store.attrs.items()
                 if not k.startswith("physics.") or k.removeprefix("physics.") not in PARAMETERS}
        attrs.update(status=STATUS_NAMES.get(store.status, str(store.status)), message=store.message,
                     t_reached=float(store.progress[0]), source=str(path), Conventions=CONVENTIONS,
                     title=f"hpcves case {case or path.stem}")
        attrs = netcdf_attrs(attrs)
        physics = {k: float(parameter_of(store.attrs, k, "physics.")) for k in PARAMETERS}
        N = store.width
    t = data.pop("t")
    coords = {"time": t[1], "xy": ("xy", ["x", "y"], {"long_name": "component"}), **physics}
    if snapshots:
        coords["snapshot"] = data.pop("snapshot_t")[1]
        coords["alpha"] = np.arange(N) / N
    ds = xr.Dataset({k: xr.Variable(*v) for k, v in data.items()}, coords=coords, attrs=attrs)
    ds["time"].attrs.update(t[2], axis="T")         # CF: the time axis, for cf-xarray and others
    if snapshots:
        ds["snapshot"].attrs.update(_attrs(SNAPSHOT_ATTRS, "t"))
        ds["alpha"].attrs.update(_attrs(SNAPSHOT_ATTRS, "alpha"))
    for k in PARAMETERS:
        ds[k].attrs.update(parameter_attrs(k))
    return ds


def open_campaign(path, *, variables=None, tree: bool = False):
    """Every case of a campaign file as one xarray Dataset over (case, sample): each case's series
    from its first sample to its last computed one, NaN beyond (cases differ in length and in
    sampling, so the time is the variable ``t`` (case, sample), not a shared axis); the parameters,
    status and search index as coordinates along ``case``; and, where the file
    was analysed (``hpcves analyze``), each case's regime, period, mean inclination and their error bars.

    ``variables``: the series to read (default: all). A case whose data cannot be read comes back
    with status "damaged" and NaN series. ``tree``: the file as an xarray DataTree instead --
    ``/cases`` this Dataset, ``/analysis`` every column of the analysis (where analysed), and
    ``/refinement`` (with ``/refinement/boundaries``) or ``/search``: the verdict of every
    refinement or search of a refine or search file, replayed from its analysed cases.

    The parameters select cases, ``ds.sel(shear_rate=40, psi_bar=0.3)``, and ``ds.hpcves.case(...)`` gives
    one case over its own time axis (reports/selection.py)."""
    import xarray as xr

    from hpcves.reports import selection

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
                if store.problems() or campaign.swept_disagree(i, store.case):
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
        analysis = _analysis_table(h5["analysis"]) if "analysis" in h5 and "case" in h5["analysis"] else None
        results = {}
        if analysis is not None and list(analysis["columns"]["case"]) == ids:    # an analysis of these cases
            results = {c: analysis["columns"][c] for c in RESULTS if c in analysis["columns"]}
        attrs = {"title": f"hpcves campaign {campaign.name!r}", "Conventions": CONVENTIONS,
                 "name": campaign.name, "mode": campaign.mode, "sweep_keys": ",".join(campaign.sweep_keys),
                 "campaign_toml": campaign.stored_text(str(path)), "source": str(path)}
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
    flags, flag_attrs = status_flag(statuses)
    coords = {"case": ("case", ids, {"long_name": "case id"}),
              "status": ("case", statuses, result_attrs("status")),
              "status_flag": ("case", flags, flag_attrs),
              "search": ("case", searches, {"long_name": "search of the case",
                                            "comment": "the search or refinement the case belongs to; -1 in a grid"}),
              **{k: ("case", np.asarray(v), parameter_attrs(k)) for k, v in parameters.items()}}
    if "centroid" in data:
        coords["xy"] = ("xy", ["x", "y"], {"long_name": "component"})
    ds = xr.Dataset(data, coords=coords, attrs=attrs)
    ds.coords["sample"] = ("sample", np.arange(ds.sizes.get("sample", 0)),
                           {"long_name": "sample", "comment": "index of the sample in its case's record"})
    ds = selection.with_parameter_index(ds, PARAMETERS)
    for column, values in results.items():
        ds[column] = ("case", values, result_attrs(column))
    if "regime" in results:
        ds["regime_flag"] = ("case", *regime_flag(results["regime"]))
    if not tree:
        return ds
    return _campaign_tree(path, ds, analysis)


def _analysis_table(group) -> dict:
    """{column: values} of a file's ``analysis/`` group (text columns as str), and its attributes
    under "attrs"."""
    columns = {}
    for name in group:
        values = group[name][:]
        columns[name] = (np.array([attr_text(v) for v in values], dtype=str) if values.dtype.kind in "OS"
                         else np.asarray(values, dtype=float))
    return {"columns": columns, "attrs": {k: attr_text(v) if isinstance(v, bytes) else v
                                          for k, v in group.attrs.items()}}


def table_dataset(rows: list[dict], dim: str, columns, attrs: dict | None = None):
    """CSV-like rows (dicts over ``columns``) as a Dataset over ``dim``: numbers as float, the rest as str."""
    import xarray as xr

    data = {}
    for column in columns:
        values = [row.get(column, np.nan) for row in rows]
        numeric = all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
                      for v in values)
        data[column] = (dim, np.asarray(values, dtype=float) if numeric else np.array([str(v) for v in values]),
                        result_attrs(column))
    return xr.Dataset(data, coords={dim: (dim, np.arange(len(rows)), {"long_name": f"index of the {dim}"})},
                      attrs=attrs or {})


def _campaign_tree(path: Path, cases, analysis: dict | None):
    """The DataTree of :func:`open_campaign` (``tree=True``)."""
    import xarray as xr

    nodes = {"/": xr.Dataset(attrs=cases.attrs), "/cases": cases.drop_attrs(deep=False)}
    if analysis is not None:
        from hpcves.reports.analyze import COLUMNS

        columns = analysis["columns"]
        order = [c for c in COLUMNS if c in columns] + sorted(set(columns) - set(COLUMNS))
        table = xr.Dataset({k: ("case", columns[k], result_attrs(k)) for k in order if k != "case"},
                           coords={"case": ("case", columns["case"], {"long_name": "case id"})},
                           attrs=netcdf_attrs(analysis["attrs"]))
        table = table.set_coords([k for k in PARAMETERS if k in table])
        if "regime" in table:
            table["regime_flag"] = ("case", *regime_flag(table["regime"].values))
        nodes["/analysis"] = table
        nodes.update(_replayed(path, cases.attrs["mode"]))
    return xr.DataTree.from_dict(nodes)


def _replayed(path: Path, mode: str) -> dict:
    """{node: Dataset} of the refinements (refine file) or searches (search file) replayed from the
    file's analysed cases (reports/analyze.py ``findings``), as refinement.csv, boundaries.csv and
    critical_shear.csv give them; {} for a grid, or where the analysis is of other cases than the file's."""
    if mode not in ("refine", "search"):
        return {}
    from hpcves.reports import analyze, critical, refinement

    source, rows = analyze.read_source(path), analyze.read_back(path)
    if [row["case"] for row in rows] != [case.case_id for case in source.cases]:
        return {}
    found = analyze.findings(source, rows)
    if mode == "refine":
        return {"/refinement": table_dataset([o.row() for o in found.refined], "refinement",
                                             refinement.refinement_columns(found.study)),
                "/refinement/boundaries": table_dataset(found.lines, "point",
                                                        refinement.boundary_columns(found.study))}
    return {"/search": table_dataset(found.searches, "search", critical.critical_columns(found.study.search.along))}
