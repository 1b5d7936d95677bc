"""The files as any scientific-Python tool reads them: hpcves.open_case / open_campaign (xarray),
the raw groups through h5netcdf (dimension scales, units), and plain h5py agreeing with both."""
import re

import h5py
import numpy as np
import pytest

import hpcves
from conftest import tiny_study
from hpcves.campaign.study import study_from_toml
from hpcves.run.store import FileFormatError
from hpcves.run.verdict import PARAMETERS

CASE = """
[physics]
shear_rate = 80
psi_bar = 0.3
[numerics]
N = 32
dt = 1e-3
[run]
t_end = 0.2
max_spectral_tail = 1.0
sample_interval = 0.01
snapshot_interval = 0.05
checkpoint_interval = 0.1
"""


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("datasets")
    study = campaign_study(tmp / "xr.h5")
    assert hpcves.run_campaign(study).counts["finished"] == 4
    hpcves.analyze(study.output, tmp / "analysis", case_figures=False)
    return study.output


def campaign_study(path):
    return study_from_toml(tiny_study(path, "xr", t_end=0.4, checkpoint=0.2, psi="[0.0, 0.3]", sample=0.01,
                                      snapshot=0.1))


def test_a_campaign_opens_in_xarray_trimmed_with_parameters_and_regimes_as_h5py_reads_it(campaign):
    ds = hpcves.open_campaign(campaign)
    assert dict(ds.sizes) == {"case": 4, "sample": 41, "xy": 2}            # t = 0, 0.01, ..., 0.4
    assert list(ds["case"].values) == ["0000", "0001", "0002", "0003"]
    assert list(ds["shear_rate"].values) == [40, 40, 80, 80] and list(ds["psi_bar"].values) == [0, 0.3, 0, 0.3]
    assert set(ds["status"].values) == {"finished"} and set(ds["regime"].values) <= {"TT", "PT", "TU", "undecided"}
    assert ds["theta"].attrs["units"] == "rad" and "inclination" in ds["theta"].attrs["long_name"]
    assert not np.isnan(ds["theta"]).any() and not np.isnan(ds["t"]).any()  # nothing beyond what was computed
    with h5py.File(campaign, "r") as h5:
        for i, case in enumerate(ds["case"].values):
            group, row = h5["blocks/0/timeseries"], int(h5["index/row"][i])
            n = int(group["length"][row])
            column = {q.decode() if isinstance(q, bytes) else q: k for k, q in enumerate(group["quantity"][:])}
            series = group["series"][row]                                   # (sample, quantity): format 3
            assert n == 41 and np.isnan(series[n:]).all()                   # the raw file: NaN padded
            assert np.array_equal(ds["theta"].values[i], series[:n, column["theta"]])
            assert np.array_equal(ds["centroid"].values[i], series[:n, [column["centroid_x"], column["centroid_y"]]])
            assert np.array_equal(ds["t"].values[i], series[:n, column["t"]])
        regimes = [r.decode() if isinstance(r, bytes) else r for r in h5["analysis/regime"][:]]
    assert list(ds["regime"].values) == regimes
    # selection by parameter, the xarray way
    pt = ds.where((ds.shear_rate == 80) & (ds.psi_bar == 0.3), drop=True)
    assert list(pt["case"].values) == ["0003"]
    assert "t" not in ds.coords                    # a variable: NaN beyond a case's end is no coordinate's
    few = hpcves.open_campaign(campaign, variables=["theta"])
    assert list(few.data_vars) == ["t", "theta", "regime", "period", "period_err", "period_dt_err", "period_N_err",
                                   "theta_mean", "theta_mean_err", "theta_mean_dt_err", "theta_mean_N_err",
                                   "t_settle", "cycles", "bending_gap", *(f"{name}{part}" for name in (
                                       "intrinsic_viscosity", "normal_stress_coefficient")
                                       for part in ("", "_err", "_dt_err", "_N_err")), "reason", "regime_flag"]
    assert few["intrinsic_viscosity"].attrs["long_name"] == "intrinsic viscosity [eta]"
    undecided = few["regime"] == "undecided"                  # runs this short settle nowhere: no settled mean
    assert undecided.all() and np.isnan(few["intrinsic_viscosity"]).all()
    with pytest.raises(FileFormatError, match="no series thetta"):
        hpcves.open_campaign(campaign, variables=["thetta"])


def test_cases_are_selected_by_their_parameters_and_one_case_comes_on_its_own_time_axis(campaign):
    """ds.sel(shear_rate=..., psi_bar=...) on the campaign Dataset (the case ids stay), and
    ds.hpcves.case(...): that case as open_case gives it, time its dimension."""
    ds = hpcves.open_campaign(campaign)
    one = ds.sel(shear_rate=80, psi_bar=0.3)
    assert "case" not in one.dims and str(one["case"].values) == "0003"
    assert np.array_equal(one["theta"].values, ds["theta"].values[3])
    both = ds.sel(shear_rate=80)                              # not every swept parameter named: a subset
    assert list(both["case"].values) == ["0002", "0003"]
    assert list(both.sel(psi_bar=0.3)["case"].values.ravel()) == ["0003"]       # chained
    assert list(ds.sel(shear_rate=slice(50, None), psi_bar=[0.0])["case"].values) == ["0002"]
    assert str(ds.sel(shear_rate=79, psi_bar=0.31, method="nearest")["case"].values) == "0003"
    assert list(ds.sel(case="0001")["psi_bar"].values.ravel()) == [0.3]            # by id, as before
    assert str(ds.sel(shear_rate=80.0004, psi_bar=0.3)["case"].values) == "0003"   # as a table prints it
    with pytest.raises(KeyError, match=r"no case with shear_rate = 60 \(the cases have shear_rate = 40, 80\)"):
        ds.sel(shear_rate=60)
    case = ds.hpcves.case(shear_rate=80, psi_bar=0.3)
    alone = hpcves.open_case(campaign, "0003", snapshots=False)
    assert case["theta"].dims == ("time",) and np.array_equal(case["time"].values, alone["time"].values)
    assert np.array_equal(case["theta"].values, alone["theta"].values)
    assert case["time"].attrs["long_name"] == "time t" == alone["time"].attrs["long_name"]
    assert ds.hpcves.case("0003").identical(case)
    with pytest.raises(KeyError, match="2 cases have shear_rate = 80"):
        ds.hpcves.case(shear_rate=80)


def assert_cf(ds):
    """What CF-1.11 asks of hpcves' Datasets, and what a plot needs of them: Conventions; on every variable
    a long_name short enough to label an axis, and units only where a quantity has them (a dimensionless
    one leaves them out, as CF allows, so no axis reads "[1]"); flags of the variable's type; attribute
    names without dots; no missing value in any coordinate."""
    assert ds.attrs["Conventions"] == "CF-1.11"
    for name, var in ds.variables.items():
        assert var.attrs.get("long_name"), name
        assert len(var.attrs["long_name"]) <= 40, (name, var.attrs["long_name"])
        assert var.attrs.get("units") != "1", name
        if "flag_values" in var.attrs:
            assert var.attrs["flag_values"].dtype == var.dtype
            assert len(var.attrs["flag_meanings"].split()) == len(var.attrs["flag_values"])
        assert not [k for k in var.attrs if "." in k], name
        if name in ds.coords and var.dtype.kind == "f":
            assert not np.isnan(var.values).any(), name
    assert not [k for k in ds.attrs if "." in k]


def test_the_hpcves_engine_a_datatree_and_cf_metadata_and_netcdf_readers(campaign, tmp_path):
    """`xr.open_dataset(path, engine="hpcves")`, a DataTree, CF attributes (checked by hand and by
    cf-xarray), and the raw file and the Datasets through h5netcdf and netCDF4-python."""
    xr = pytest.importorskip("xarray")
    pytest.importorskip("cf_xarray")                     # registers the .cf accessor
    netCDF4 = pytest.importorskip("netCDF4")
    assert "hpcves" in xr.backends.list_engines()
    ds = xr.open_dataset(campaign, engine="hpcves")
    assert ds.identical(hpcves.open_campaign(campaign))
    assert_cf(ds)
    assert ds["shear_rate"].attrs == {"long_name": "shear rate S", "comment": "dimensionless shear rate S"}
    assert "units" not in ds["period"].attrs and ds["theta_mean"].attrs["units"] == "rad"
    assert "period of the inclination" in ds["period"].attrs["comment"]        # the whole description
    assert ds["regime_flag"].cf.is_flag_variable and ds["status_flag"].cf.is_flag_variable
    for code, meaning in (("TT", "tank_treading"), ("PT", "phase_treading"), ("undecided", "undecided")):
        assert np.array_equal(ds["regime_flag"].cf == meaning, ds["regime"] == code)
    assert (ds["status_flag"].cf == "finished").all()
    assert "T" not in ds.cf.axes                       # no shared time axis: each case has its own (t a variable)
    one = xr.open_dataset(campaign, engine="hpcves", case="0003")
    assert one.identical(hpcves.open_case(campaign, "0003"))
    assert one.cf["T"].name == "time"                                   # cf-xarray finds the time
    assert_cf(one)
    assert "numerics_N" in one.attrs and one.attrs["status"] == "finished"

    tree = xr.open_datatree(campaign, engine="hpcves")
    assert tree.identical(hpcves.open_campaign(campaign, tree=True))
    assert set(tree.children) == {"cases", "analysis"}               # a grid: no refinement, no search
    assert tree["cases"].to_dataset().identical(ds.drop_attrs(deep=False))
    analysis = tree["analysis"].to_dataset()
    assert list(analysis["regime"].values) == list(ds["regime"].values)
    assert {"theta_amplitude", "soft_domains", "pattern_speed"} <= set(analysis.data_vars)
    assert analysis["soft_domains"].attrs["long_name"].startswith("soft domains")
    for node in tree.subtree:
        assert not [k for k in node.attrs if "." in k], node.path

    # the Datasets and the tree as netCDF files, read back by netCDF4-python and h5netcdf
    ds.to_netcdf(tmp_path / "cases.nc", engine="netcdf4")
    with netCDF4.Dataset(tmp_path / "cases.nc") as nc:
        assert nc.Conventions == "CF-1.11" and nc["theta"].units == "rad"
        assert list(nc["regime_flag"].flag_values) == [0, 1, 2, 3]
    assert xr.open_dataset(tmp_path / "cases.nc").identical(ds.drop_indexes(PARAMETERS).drop_encoding())
    tree.to_netcdf(tmp_path / "tree.nc", engine="h5netcdf")
    back = xr.open_datatree(tmp_path / "tree.nc", engine="h5netcdf")
    assert list(back["analysis/regime"].values) == list(ds["regime"].values)
    # the raw campaign file opens in both netCDF readers (its groups as HDF5 holds them)
    for engine in ("h5netcdf", "netcdf4"):
        raw = xr.open_datatree(campaign, engine=engine, **({"phony_dims": "sort"} if engine == "h5netcdf" else {}))
        assert raw["blocks/0/timeseries"]["series"].dims == ("case", "sample", "quantity")
        raw.close()


def test_a_run_file_through_netcdf_readers_has_no_missing_values_in_its_coordinates(tmp_path):
    """The raw run file's rows are preallocated: its dimensions are sample and snapshot indices, and t
    (NaN beyond what was computed) a variable over them."""
    xr = pytest.importorskip("xarray")
    pytest.importorskip("netCDF4")
    toml = tmp_path / "case.toml"
    toml.write_text(CASE)
    path = tmp_path / "case.h5"
    hpcves.run_case(toml, path, max_steps=60, progress=False)                 # part way: a NaN tail
    for engine in ("h5netcdf", "netcdf4"):
        for group in ("timeseries", "snapshots"):
            raw = xr.open_dataset(path, engine=engine, group=group,
                                  **({"phony_dims": "sort"} if engine == "h5netcdf" else {}))
            assert raw["t"].dims == (("sample",) if group == "timeseries" else ("snapshot",))
            assert np.isnan(raw["t"].values).any()                           # preallocated rows
            for dim in raw.dims:
                if dim in raw.coords:
                    assert not np.isnan(raw[dim].values.astype(float)).any(), (engine, group, dim)
            raw.close()
    ds = xr.open_dataset(path, engine="hpcves")
    assert_cf(ds)
    assert ds.attrs["status"] == "interrupted" and not np.isnan(ds["time"].values).any()


def test_one_case_of_a_campaign_and_its_raw_groups_through_h5netcdf(campaign):
    xr = pytest.importorskip("xarray")
    pytest.importorskip("h5netcdf")
    one = hpcves.open_case(campaign, "0003")
    assert dict(one.sizes) == {"time": 41, "xy": 2, "snapshot": 5, "alpha": 32}
    assert float(one["shear_rate"]) == 80 and one.attrs["status"] == "finished"
    assert one["psi"].dims == ("snapshot", "alpha") and one["alpha"].values[1] == 1 / 32
    # the raw groups: the dimension scales are netCDF dimensions, the attributes come along
    raw = xr.open_dataset(campaign, engine="h5netcdf", group="blocks/0/timeseries", phony_dims="sort")
    assert raw["series"].dims == ("case", "sample", "quantity")          # campaign format 3: packed
    theta = raw["series"].sel(quantity="theta")
    assert raw["units"].sel(quantity="theta") == "rad"
    assert list(raw["quantity"].values[6:9]) == ["centroid_x", "centroid_y", "tension_min"]
    n = int(raw["length"][3])
    assert np.array_equal(theta.values[3, :n], one["theta"].values)
    assert np.array_equal(raw["series"].sel(quantity=["centroid_x", "centroid_y"]).values[3, :n],
                          one["centroid"].values)
    snaps = xr.open_dataset(campaign, engine="h5netcdf", group="blocks/0/snapshots", phony_dims="sort")
    assert snaps["fields"].dims == ("case", "snapshot", "field", "alpha")
    assert str(snaps["long_name"].sel(field="psi").values).startswith("soft-phase")
    assert np.array_equal(snaps["fields"].sel(field="psi").values[3, :int(snaps["length"][3])], one["psi"].values)
    raw.close()
    snaps.close()
    for args, words in (((campaign,), "name the case"), ((campaign, "0009"), "no case '0009'")):
        with pytest.raises(FileFormatError, match=words):
            hpcves.open_case(*args)


def test_the_python_api_shows_progress_bars_unless_told_not_to(campaign, capsys):
    """A notebook user saw nothing while run_case / run_campaign worked (tqdm.auto: text here)."""
    again = hpcves.run_campaign(campaign_study(campaign), campaign, resume=True)   # all ended before
    assert again.ran == ()
    assert re.search(r"xr: 100%\|[^|]+\| .*4/4 cases, 0 running, 0 failed", capsys.readouterr().err)
    hpcves.run_campaign(campaign_study(campaign), campaign, resume=True, progress=False)
    assert capsys.readouterr().err == ""
    from hpcves.api import CaseBar
    from hpcves.run.runner import Tick

    bar = CaseBar("case.h5")
    for t in (0.1, 0.4):
        bar(Tick(t=t, t_end=0.4, steps_per_second=1234.0, eta_seconds=1.0, theta=0.5))
    bar.close()
    assert re.search(r"case.h5: 100%\|[^|]+\| .*1,234 steps/s, theta = 0.500", capsys.readouterr().err)


def test_the_python_api_runs_resumes_opens_and_classifies_a_case(tmp_path):
    toml = tmp_path / "case.toml"
    toml.write_text(CASE)
    path = tmp_path / "case.h5"
    first = hpcves.run_case(toml, path, max_steps=120)                  # stops part way, resumable
    assert first.steps == 120 and first.t < 0.2
    with pytest.raises(FileFormatError, match="exists already"):
        hpcves.run_case(toml, path)
    done = hpcves.run_case(None, path, resume=True)
    assert done.t == pytest.approx(0.2)
    whole = tmp_path / "whole.h5"
    hpcves.run_case(hpcves.load_case(toml), whole)
    a, b = hpcves.open_case(path), hpcves.open_case(whole)
    assert a.attrs["status"] == "finished" and a.sizes["time"] == 21
    assert np.array_equal(a["theta"].values, b["theta"].values)          # resumed = uninterrupted, bitwise
    found = hpcves.classify(a)
    assert found.regime in ("TT", "PT", "TU", "undecided") and found.reason
    series = {k: a[k].values for k in ("theta", "V_psi", "V_L", "tank_treading_velocity")}
    again = hpcves.classify({"t": a["time"].values, **series})
    assert (again.regime, again.reason) == (found.regime, found.reason)
    with pytest.raises(FileFormatError, match="not a campaign file"):
        hpcves.open_campaign(path)
