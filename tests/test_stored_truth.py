"""Nothing silently wrong (issue 64): what decides what runs or what is reported is checksummed or checked
against what is, and every reader honours the checks.

* a run file's ``config`` attribute (what a resume runs) and its parameter attributes (what analyze and
  the xarray engine read) must agree;
* a campaign file's stored study (``campaign_toml``: what replays its searches, names its starts and
  holds its thresholds) carries a checksum; a file without one is checked against its fingerprint;
* the index's swept values (what tables, diagrams and growth read) must be what each case ran;
* ``open_case`` and the xarray engine refuse data that fail their checksums, as analyze does;
* a grid that grows with its ``[starts]`` in another order is refused (its kept cases were labelled
  with the wrong start).
"""
import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest

from conftest import tiny_study, write_tiny_study
from hpcves.campaign.driver import run_campaign
from hpcves.campaign.study import study_from_toml
from hpcves.config import case_from_toml
from hpcves.errors import FileFormatError
from hpcves.reports.datasets import open_campaign, open_case
from hpcves.run.store import FINISHED, INTERRUPTED
from jobs import SHORT, case_view, run_in_process

HPCVES = [sys.executable, "-m", "hpcves.cli"]
CASE = SHORT.format(t_end=0.1, checkpoint=0.04)


def hpcves(*args):
    return subprocess.run(HPCVES + [str(a) for a in args], capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def run_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("truth")
    case = case_from_toml(CASE)
    assert run_in_process(case, d / "whole.h5").status == FINISHED
    assert run_in_process(case, d / "cut.h5", max_steps=50).status == INTERRUPTED
    return d


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    d = tmp_path_factory.mktemp("truth_campaign")
    output = d / "grid.h5"
    assert run_campaign(study_from_toml(tiny_study(output, name="grid", psi=None)), output).exit_status == 0
    return output


@pytest.mark.parametrize("edit", ["config", "attribute"])
def test_a_run_file_whose_config_and_parameter_attributes_disagree_is_refused_by_every_reader(run_files, tmp_path,
                                                                                               edit):
    """The config attribute edited to another shear rate resumed with the other physics while the
    parameter attributes (what analyze and xarray read) kept the old one."""
    for name in ("cut.h5", "whole.h5"):
        shutil.copy(run_files / name, tmp_path / name)
        with h5py.File(tmp_path / name, "r+") as f:
            if edit == "config":
                text = f.attrs["config"]
                text = text.decode() if isinstance(text, bytes) else text
                assert "shear_rate = 80.0" in text
                f.attrs["config"] = text.replace("shear_rate = 80.0", "shear_rate = 85.0")
            else:
                f.attrs["physics.shear_rate"] = 85.0
    said = "its config says physics.shear_rate = " + ("85.0" if edit == "config" else "80.0")
    before = (tmp_path / "cut.h5").read_bytes()
    resumed = hpcves("run", "--resume", tmp_path / "cut.h5")
    assert resumed.returncode == 2 and "damaged, not resumed" in resumed.stderr and said in resumed.stderr, \
        resumed.stderr
    assert (tmp_path / "cut.h5").read_bytes() == before
    analyzed = hpcves("analyze", tmp_path / "whole.h5", "--out", tmp_path / "a")
    assert analyzed.returncode == 2 and said in analyzed.stderr, analyzed.stderr
    with pytest.raises(FileFormatError, match="damaged, not read .*" + said):
        open_case(tmp_path / "whole.h5")


def test_open_case_and_the_engine_refuse_values_that_fail_their_checksums(run_files, campaign, tmp_path):
    """analyze refused the file; open_case and xr.open_dataset(engine="hpcves") handed the values out."""
    import xarray as xr

    path = tmp_path / "whole.h5"
    shutil.copy(run_files / "whole.h5", path)
    assert open_case(path)["theta"].size > 0                 # sound: read
    with h5py.File(path, "r+") as f:
        values = f["timeseries/theta"][()]
        values.view(np.uint64)[3] ^= np.uint64(1)
        f["timeseries/theta"][()] = values
    for read in (lambda: open_case(path), lambda: xr.open_dataset(path, engine="hpcves")):
        with pytest.raises(FileFormatError, match="timeseries/theta fails its checksum"):
            read()
    copy = tmp_path / "grid.h5"
    shutil.copy(campaign, copy)
    with h5py.File(copy, "r+") as f:
        case = case_view(f, "0001")
        values = case["timeseries/theta"]
        values.view(np.uint64)[3] ^= np.uint64(1)
        case["timeseries/theta"] = values
    with pytest.raises(FileFormatError, match="case 0001: damaged, not read .*timeseries/theta fails its checksum"):
        open_case(copy, "0001")
    assert open_case(copy, "0000")["theta"].size > 0           # the other case is sound
    ds = open_campaign(copy)
    assert list(ds["status"].values) == ["finished", "damaged"]
    assert np.all(np.isnan(ds["theta"].sel(case="0001").values))


def _edit_text(path, old, new):
    with h5py.File(path, "r+") as f:
        text = f.attrs["campaign_toml"]
        text = text.decode() if isinstance(text, bytes) else text
        assert old in text
        f.attrs["campaign_toml"] = text.replace(old, new, 1)


def test_a_stored_study_that_fails_its_checksum_is_refused_by_status_analyze_resume_and_xarray(campaign, tmp_path):
    """One character of a search file's stored study turned a converged search into a running one
    (status --check exit 3: a batch chain would resubmit). Whatever reads the text checks it first."""
    path = tmp_path / "grid.h5"
    shutil.copy(campaign, path)
    _edit_text(path, "sample_interval = 0.005", "sample_interval = 0.006")
    said = "its stored study (campaign_toml) fails its checksum"
    checked = hpcves("status", "--check", path)
    assert checked.returncode == 2 and said in checked.stdout + checked.stderr, (checked.stdout, checked.stderr)
    analyzed = hpcves("analyze", path, "--out", tmp_path / "a")
    assert analyzed.returncode == 2 and said in analyzed.stderr, analyzed.stderr
    with pytest.raises(FileFormatError, match=said.replace("(", r"\(").replace(")", r"\)")):
        open_campaign(path)
    study = study_from_toml(tiny_study(campaign, name="grid", psi=None))
    with pytest.raises(FileFormatError, match=r"campaign_toml\) fails its checksum"):
        run_campaign(study, path, resume=True)


def test_a_file_made_before_the_checksum_is_checked_against_its_fingerprint(campaign, tmp_path):
    path = tmp_path / "grid.h5"
    shutil.copy(campaign, path)
    with h5py.File(path, "r+") as f:
        del f.attrs["campaign_toml_sha256"]                     # as files made before it existed
    assert hpcves("status", "--check", path).returncode == 0
    assert open_campaign(path).sizes["case"] == 2
    _edit_text(path, "t_end = 0.1", "t_end = 0.2")              # changes the cases: another fingerprint
    checked = hpcves("status", "--check", path)
    assert checked.returncode == 2 and "is not the study of its fingerprint" in checked.stdout + checked.stderr, \
        (checked.stdout, checked.stderr)


def test_an_edited_swept_value_in_the_index_is_named_by_every_reader(campaign, tmp_path):
    """A parameter edited in the campaign's index showed in status --check with exit 0."""
    path = tmp_path / "grid.h5"
    shutil.copy(campaign, path)
    with h5py.File(path, "r+") as f:
        f["index/shear_rate"][1] = 60.0
    said = "index/shear_rate lists 60, its config ran shear_rate = 80"
    checked = hpcves("status", "--check", path)
    assert checked.returncode == 2 and said in checked.stdout, (checked.stdout, checked.stderr)
    analyzed = hpcves("analyze", path, "--out", tmp_path / "a")
    assert analyzed.returncode == 2 and said in analyzed.stdout + analyzed.stderr, analyzed.stderr
    assert list(open_campaign(path)["status"].values) == ["finished", "damaged"]
    study = study_from_toml(tiny_study(campaign, name="grid", psi=None))
    with pytest.raises(FileFormatError, match="case 0001: " + said):
        run_campaign(study, path, resume=True)


STARTS = '[starts]\nellipse = {}\nsmoothed = { initial_shape = "smoothed" }\n'
REORDERED = '[starts]\nsmoothed = { initial_shape = "smoothed" }\nellipse = {}\n'
ADDED = STARTS + 'narrow = { delta = 0.05 }\n'


def test_a_grid_grown_with_its_starts_reordered_is_refused_and_one_with_a_start_added_keeps_the_labels(tmp_path):
    """The same starts in another order labelled kept cases with the wrong start (a case run from the
    ellipse shown as the other one)."""
    from hpcves.reports.analyze import read_source

    study_file, output = write_tiny_study(tmp_path, name="starts", t_end=0.01, shear="[40]", psi=None,
                                          extra=STARTS)
    assert run_campaign(study_from_toml(study_file.read_text()), output).exit_status == 0
    labels = dict(zip((c.case_id for c in read_source(output).cases), read_source(output).starts))
    assert labels == {"0000": "ellipse", "0001": "smoothed"}
    reordered = study_file.read_text().replace(STARTS, REORDERED)
    with pytest.raises(FileFormatError, match=r"\[starts\] \(ellipse, smoothed -> smoothed, ellipse\)"):
        run_campaign(study_from_toml(reordered), output, resume=True)
    grown = study_file.read_text().replace(STARTS, ADDED)
    assert run_campaign(study_from_toml(grown), output, resume=True).exit_status == 0
    source = read_source(output)
    assert dict(zip((c.case_id for c in source.cases), source.starts)) == {"0000": "ellipse", "0001": "smoothed",
                                                                           "0002": "narrow"}
