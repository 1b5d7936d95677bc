"""The [search] campaign mode: critical-shear searches run by the campaign runner, end to end.

Tiny real cases (N = 32, t_end = 1.5): at Delta = 0.194 the homogeneous
vesicle tank-treads at every S (no S_C in the range), psi_bar = 0.3 goes from
TT to PT between S = 70 and 85 (VALIDATION.md: TT at 40, PT at 80).
"""
import csv
import os
import shutil
import signal

import h5py
import numpy as np
import pytest

from conftest import TINY_RUN
from hpcves.analysis.search import CONVERGED, UNBRACKETED, centre_only
from hpcves.campaign import file as campaign_file
from hpcves.campaign.driver import run_campaign
from hpcves.campaign.study import study_from_toml
from hpcves.errors import FileFormatError
from hpcves.model.params import ConfigError
from hpcves.reports.analyze import analyze
from hpcves.reports.critical import CRITICAL_COLUMNS
from hpcves.reports.datasets import open_campaign
from hpcves.run.store import FINISHED, superblock_version
from jobs import assert_same_results, case_view, case_views, hpcves, job_pids, start_job, wait_until, writing_format
from test_campaign import needs_mpi, statuses

SEARCH = """
[campaign]
name = "search"
output = "{output}"
t_end = 1.5
""" + TINY_RUN + """[search]
low = 30.0
high = 120.0
rel_tol = 0.25
[sweep]
psi_bar = [0.0, 0.3]
"""


def write_search(tmp_path, checkpoint=0.5):
    output = tmp_path / "search.h5"
    path = tmp_path / "search.toml"
    path.write_text(SEARCH.format(output=output, checkpoint=checkpoint))
    return path, output


def stop_before_stage_2(monkeypatch):
    """Make a search stop (KeyboardInterrupt) as it would add its second stage's cases."""
    from hpcves.campaign import stages

    real_add = stages.add_stage

    def stop_at_stage_2(path, comm, cases, stage, source):
        if stage == 2:
            raise KeyboardInterrupt
        return real_add(path, comm, cases, stage, source)

    monkeypatch.setattr(stages, "add_stage", stop_at_stage_2)


@pytest.fixture(scope="module")
def searched(tmp_path_factory):
    """The tiny search run serially in this process: (study, file, summary)."""
    path, output = write_search(tmp_path_factory.mktemp("search"))
    study = study_from_toml(path.read_text())
    stages = []
    summary = run_campaign(study, output, on_stage=stages.append)
    assert summary.exit_status == 0
    return study, output, summary, stages


def assert_estimate(value, found_from, state):
    """A critical value reported as a best estimate lies inside the bracket; where nothing better was found,
    it is the bracket's centre and says so."""
    assert state.low <= value <= state.high, (value, state)
    if centre_only(found_from):
        assert value == pytest.approx(state.centre, rel=1e-5)              # a CSV keeps 6 digits
    else:
        assert "->" in found_from, found_from
    return True


def test_the_searches_bracket_s_c_or_say_it_lies_outside(searched):
    study, output, summary, stages = searched
    homogeneous, mixed = summary.searches
    assert homogeneous.point["psi_bar"] == 0.0 and homogeneous.state.status == UNBRACKETED
    assert "S_C > 120" in homogeneous.state.reason and set(homogeneous.regimes.values()) == {"TT"}
    assert mixed.state.status == CONVERGED
    low, high = mixed.state.low, mixed.state.high
    assert 60 < low < high < 90 and high / low - 1 <= 0.25          # TT at 70 (N = 64), PT at 80
    assert mixed.regimes[low] == "TT" and mixed.regimes[high] == "PT"
    assert mixed.state.centre == pytest.approx((low * high) ** 0.5)
    assert len(mixed.regimes) <= study.search.cases_needed()
    # stage by stage: both ends first, then one bisection at a time for the search still running
    assert [len([o for o in s if o.state.status == "running"]) for s in stages][-1] == 0
    assert summary.searches == tuple(stages[-1])


def test_the_file_holds_every_case_of_every_stage(searched):
    study, output, summary, _ = searched
    n = sum(len(o.regimes) for o in summary.searches)
    with h5py.File(output, "r") as f:
        assert f.attrs["mode"] == "search" and f.attrs["n_cases"] == n == len(case_views(f))
        ids = [i.decode() for i in f["index/case_id"][:]]
        assert ids == [f"{i:04d}" for i in range(n)]
        assert list(f["index/search"][:4]) == [0, 0, 1, 1]                 # stage 1: both ends of both
        assert list(f["index/shear_rate"][:4]) == [30, 120, 30, 120]
        assert list(f["searches/psi_bar"][:]) == [0.0, 0.3]
        for case_id, search, shear_rate in zip(ids, f["index/search"][:], f["index/shear_rate"][:]):
            g = case_view(f, case_id)
            assert g.attrs["physics.shear_rate"] == shear_rate
            assert g.attrs["physics.psi_bar"] == [0.0, 0.3][search]
    assert set(statuses(output).values()) == {FINISHED}


def test_the_datatree_of_a_search_file_holds_its_searches(searched, tmp_path):
    """open_campaign(tree=True) of an analysed search file: /search is critical_shear.csv as a Dataset."""
    _, reference, summary, _ = searched
    output = tmp_path / "search.h5"
    shutil.copy(reference, output)
    assert open_campaign(output, tree=True).children.keys() == {"cases"}     # not analysed: no results
    analyze(output, tmp_path / "analysis", case_figures=False)
    tree = open_campaign(output, tree=True)
    assert set(tree.children) == {"cases", "analysis", "search"}
    search = tree["search"].to_dataset()
    assert list(search["status"].values) == ["not bracketed", "converged"]
    assert np.isnan(search["S_C"].values[0])
    assert_estimate(search["S_C"].values[1], str(search["S_C_from"].values[1]), summary.searches[1].state)
    assert search["bracket_low"].attrs["long_name"] and "units" not in search["psi_bar"].attrs     # dimensionless


def test_analyze_replays_the_searches_into_critical_shear_csv(searched, tmp_path):
    _, output, summary, _ = searched
    report = analyze(output, tmp_path, write_to_file=False, case_figures=False)
    with open(tmp_path / "critical_shear.csv") as f:
        table = list(csv.DictReader(f))
    assert tuple(table[0]) == CRITICAL_COLUMNS and len(table) == 2
    mixed = summary.searches[1].state
    assert_estimate(float(table[1]["S_C"]), table[1]["S_C_from"], mixed)
    assert float(table[1]["S_C"]) == pytest.approx(report.searches[1]["S_C"], rel=1e-5)     # 6 digits
    assert float(table[1]["bracket_low"]) == pytest.approx(mixed.low)
    assert float(table[1]["bracket_high"]) == pytest.approx(mixed.high)
    assert table[0]["S_C"] == "" and table[0]["status"] == "not bracketed"
    # the bending-energy gap of the phase-treading case at the bracket's top, as regimes.csv has it
    with open(tmp_path / "regimes.csv") as f:
        cases = list(csv.DictReader(f))
    top = next(c for c in cases if float(c["psi_bar"]) == 0.3
               and float(c["shear_rate"]) == pytest.approx(mixed.high, rel=1e-5))
    assert top["regime"] == "PT" and float(top["bending_gap"]) > 0
    assert float(table[1]["bending_gap"]) == pytest.approx(float(top["bending_gap"]), rel=1e-5)
    assert 0 < float(table[1]["bending_gap_err"]) < float(table[1]["bending_gap"])
    assert table[0]["bending_gap"] == ""
    assert "Delta E_b" in (tmp_path / "critical_shear.md").read_text()
    assert [s["status"] for s in report.searches] == ["not bracketed", "converged"]
    for name in ("critical_shear", "phase_diagram"):
        assert (tmp_path / f"{name}.png").stat().st_size > 1000
    assert not (tmp_path / "periods.md").exists()            # irregular S: no period table
    # stricter thresholds can undo a verdict; the replay then says what it would need
    strict = analyze(output, tmp_path / "strict", write_to_file=False, case_figures=False,
                     overrides={"min_cycles": 40.0})
    assert strict.searches[1]["status"] != "converged"


def test_a_stage_cut_short_while_adding_its_cases_leaves_the_file_as_it_was(searched, tmp_path, monkeypatch):
    """The cases are added to a copy that replaces the file only once complete: an interruption in the
    middle of adding them leaves the file exactly as the stage before left it (and a stale .partial)."""
    _, reference, _, _ = searched
    path, output = write_search(tmp_path)
    study = study_from_toml(path.read_text())
    real_add = campaign_file.CampaignFile.add_cases
    calls = []

    def add_then_die(self, cases, source=None):
        calls.append(len(cases))
        if len(calls) == 3:              # (1: the empty creation, 2: stage 1) stage 2: rows made, index not yet
            self._blocks.add([c.case for c in cases])
            raise KeyboardInterrupt
        real_add(self, cases, source)

    monkeypatch.setattr(campaign_file.CampaignFile, "add_cases", add_then_die)
    with pytest.raises(KeyboardInterrupt):
        run_campaign(study, output)
    monkeypatch.setattr(campaign_file.CampaignFile, "add_cases", real_add)
    with h5py.File(output, "r") as f:
        assert f["index/case_id"].shape[0] == f.attrs["n_cases"] == 4
    assert (tmp_path / "search.h5.partial").exists()
    summary = run_campaign(study, output, resume=True)
    assert summary.exit_status == 0 and min(r.case_id for r in summary.ran) == "0004"
    assert not (tmp_path / "search.h5.partial").exists()
    assert_same_results(output, reference)


def test_a_half_added_stage_of_an_older_version_is_dropped_and_made_again(searched, tmp_path, monkeypatch):
    """Files of hpcves before stages were added by replacement can hold cases beyond n_cases: laid out
    and indexed, the header's count not yet raised."""
    from hpcves.campaign import stages

    _, reference, _, _ = searched
    path, output = write_search(tmp_path)
    study = study_from_toml(path.read_text())

    real_add = stages.add_stage

    def old_add(path, comm, cases, stage, source):             # what the old in-place adding could leave
        if stage == 1:
            return real_add(path, comm, cases, stage, source)
        with h5py.File(path, "r+") as h5:
            n = int(h5.attrs["n_cases"])
            campaign_file.CampaignFile(h5).add_cases(cases)
            h5.attrs["n_cases"] = n
        raise KeyboardInterrupt

    monkeypatch.setattr(stages, "add_stage", old_add)
    with pytest.raises(KeyboardInterrupt):
        run_campaign(study, output)
    monkeypatch.undo()
    with h5py.File(output, "r") as f:
        assert f["index/case_id"].shape[0] > f.attrs["n_cases"] == 4
        assert f["blocks/0/status"].shape[0] == f["index/case_id"].shape[0]
    summary = run_campaign(study, output, resume=True)
    assert summary.exit_status == 0 and min(r.case_id for r in summary.ran) == "0004"
    assert_same_results(output, reference)


def test_a_search_file_refuses_changed_thresholds_or_a_narrower_search(searched, tmp_path):
    study, output, _, _ = searched
    stricter = study_from_toml(study.source + "[analysis]\nmin_cycles = 5\n")
    assert stricter.fingerprint != study.fingerprint
    with pytest.raises(FileFormatError, match=r"different version of study 'search': the \[analysis\] thresholds"):
        run_campaign(stricter, output, resume=True)
    narrower = study_from_toml(study.source.replace("low = 30.0", "low = 40.0"))
    with pytest.raises(FileFormatError, match=r"the search narrowed \(low 30 -> 40\)"):
        run_campaign(narrower, output, resume=True)
    longer = study_from_toml(study.source.replace("t_end = 1.5", "t_end = 2"))
    with pytest.raises(FileFormatError, match="the time rules"):
        run_campaign(longer, output, resume=True)


def test_a_search_grows_by_a_tighter_tolerance_a_wider_range_and_a_new_point(searched, tmp_path):
    """rel_tol 0.25 -> 0.1, high 120 -> 240 and psi_bar 0.5 added: the searches continue in the same
    file from the cases they ran, which stay bit for bit and keep their ids and searches."""
    from jobs import _same, results

    study, reference, summary, _ = searched
    output = tmp_path / "search.h5"
    shutil.copy(reference, output)
    text = (study.source.replace("rel_tol = 0.25", "rel_tol = 0.1").replace("high = 120.0", "high = 240.0")
            .replace("psi_bar = [0.0, 0.3]", "psi_bar = [0.0, 0.3, 0.5]"))
    grown = study_from_toml(text.replace(str(reference), str(output)))
    said = []
    again = run_campaign(grown, output, resume=True, announce=lambda line, *_: said.append(line))
    assert again.exit_status == 0
    assert any("the study grew: high 120 -> 240; rel_tol 0.25 -> 0.1; 1 new search (psi_bar += 0.5)" in line
               for line in said), said
    before, after = results(reference), results(output)
    n = len(summary.ran)
    assert len(after) > n and all(_same(before[c], after[c]) for c in before if c.startswith("0"))
    with h5py.File(output, "r") as f:
        assert list(f["searches/psi_bar"][:]) == [0.0, 0.3, 0.5]
        searches = list(f["index/search"][:])
        assert searches[:n] == list(h5py.File(reference, "r")["index/search"][:n])
        assert 2 in searches[n:]
    homogeneous, mixed, new = again.searches
    assert homogeneous.state.status == UNBRACKETED and "S_C > 240" in homogeneous.state.reason   # was > 120
    assert mixed.state.status == CONVERGED and mixed.state.high / mixed.state.low - 1 <= 0.1
    assert mixed.state.low >= summary.searches[1].state.low and mixed.state.high <= summary.searches[1].state.high
    assert new.point["psi_bar"] == 0.5 and new.regimes


@pytest.mark.parametrize("text, message", [
    ("[search]\nlow = 10.0\nhigh = 100.0\n[sweep]\nshear_rate = [1, 2]\n", "leave shear_rate out of"),
    ("[search]\nlow = 10.0\nhigh = 100.0\nspan = 3\n", "unknown key span"),
    ("[search]\nlow = 10.0\n", "give high"),
    ("[search]\nlow = 100.0\nhigh = 10.0\n", "low < high"),
    ("[search]\nlow = 10.0\nhigh = 100.0\n[sweep]\npsi_bar = [0.3, 1.5]\n", "of search 1.*psi_bar"),
])
def test_bad_search_tables_are_refused(text, message):
    with pytest.raises(ConfigError, match=message):
        study_from_toml(text)


# mpio (the default with parallel h5py) is what test_refine_campaign.py kills in make test: here in make faults
@needs_mpi
@pytest.mark.parametrize("io", [pytest.param("mpio", marks=pytest.mark.faults), "relay"])
def test_mpi_search_killed_between_stages_resumes_to_the_serial_result(searched, tmp_path, io):
    """SIGKILL once the second stage runs, resume on two ranks: every case bitwise as in the serial search."""
    _, reference, _, _ = searched
    path, output = write_search(tmp_path, checkpoint=0.05)
    job = start_job(2, "campaign", path, "--quiet", "--io", io)

    def second_stage_runs():            # the file is always whole (atomic.py): read it as it is
        assert job.poll() is None, job.communicate()
        if not output.exists():
            return False
        with h5py.File(output, "r", locking=False) as f:
            return f.attrs["n_cases"] >= 5 and any(int(g["status"][()]) == 1 for _, g in case_views(f))
    wait_until(second_stage_runs, "the search's second stage runs")
    for pid in job_pids(job.pid):
        os.kill(pid, signal.SIGKILL)
    job.communicate()
    result = hpcves("campaign", path, "--resume", "--io", io, n=2)
    assert result.returncode == 0, result.stderr
    assert_same_results(output, reference, attrs=False)        # checkpointed 10 times as often
    with open(tmp_path / "search_critical_shear.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["status"] for r in rows] == ["not bracketed", "converged"]
    reference = searched[2].searches[1].state
    assert (float(rows[1]["bracket_low"]), float(rows[1]["bracket_high"])) == pytest.approx((reference.low,
                                                                                           reference.high))
    assert rows[1]["S_C"] == "" == rows[1]["S_C_from"]          # the campaign's table: the bracket, no estimate


def test_status_says_a_stage_is_left_until_the_searches_are_complete(searched, tmp_path):
    """Killed just after the first stage's four cases finished: every case in the file has ended,
    yet the mixed search has a bisection to run. status replays the searches as --resume does."""
    import json
    import signal as signals

    from jobs import mpi_env

    _, reference, _, _ = searched
    path, output = write_search(tmp_path)
    killed = hpcves("campaign", path, "--quiet", env=mpi_env(HPCVES_FAULT="finished:4"))
    assert killed.returncode == -signals.SIGKILL, killed.stderr
    status = hpcves("status", output, "--json")
    report = json.loads(status.stdout)
    assert status.returncode == 3 and report["complete"] is False, status.stdout
    assert report["totals"] == {"finished": 4} and report["left"] == "the next stage: 1 new case"
    assert "work left: the next stage: 1 new case" in hpcves("status", output).stdout
    assert hpcves("campaign", path, "--resume", "--quiet").returncode == 0
    status = hpcves("status", output, "--json")
    assert status.returncode == 0 and json.loads(status.stdout)["complete"] is True
    assert_same_results(output, reference, attrs=False)


@pytest.mark.parametrize("version", [1, 2])
def test_a_search_in_a_file_of_an_older_layout_continues_in_it(searched, tmp_path, monkeypatch, version):
    """A file of campaign format 1 (a group per case) or 2 (blocks, a dataset a record), its search cut
    short after its first stage, is continued by this hpcves in that layout (format 1: stages laid out
    as groups, run/stamp.py), to the cases and data of the search run in format 3 from the start."""
    _, reference, _, _ = searched
    path, output = write_search(tmp_path)
    study = study_from_toml(path.read_text())
    stop_before_stage_2(monkeypatch)
    with pytest.raises(KeyboardInterrupt), writing_format(version):
        run_campaign(study, output)
    monkeypatch.undo()
    with h5py.File(output, "r") as f:
        before = int(f.attrs["n_cases"])
    summary = run_campaign(study, output, resume=True)
    assert summary.exit_status == 0 and min(r.case_id for r in summary.ran) == f"{before:04d}"
    with h5py.File(output, "r") as f:
        assert f.attrs["format_version"] == version
        if version == 1:
            assert "blocks" not in f and len(f["cases"]) == f.attrs["n_cases"] > before
        else:                                               # a dataset a record, every stage's rows in it
            assert "blocks/0/timeseries/series" not in f
            assert f["blocks/0/timeseries/theta"].shape[0] == f.attrs["n_cases"] > before
    assert superblock_version(output) == (0 if version == 1 else 2)      # and in the HDF5 formats it was written in
    assert_same_results(output, reference)


LAMBDA_SEARCH = """
[campaign]
name = "lambda"
output = "{output}"
t_end = 3.0
[physics]
psi_bar = 0.0
excess_length = 0.94
""" + TINY_RUN + """[search]
along = "viscosity_ratio"
low = 2.0
high = 12.0
rel_tol = 0.6
[sweep]
shear_rate = [40.0]
"""


@pytest.fixture(scope="module")
def lambda_searched(tmp_path_factory):
    """A search along lambda for lambda_C of the homogeneous vesicle (Delta = 0.94, S = 40, N = 32):
    TT at lambda = 1 and 3, TU at 6, 10, 20 on a grid of the same cases; at 3.5 TT, 4.5 TU, and
    near lambda_C (4.0, 4.24) still undecided at t = 3 (critical slowing down), so the range and
    tolerance put the search's cases at 2, 12, 4.90 and 3.13."""
    directory = tmp_path_factory.mktemp("lambda")
    path = directory / "lambda.toml"
    path.write_text(LAMBDA_SEARCH.format(output=directory / "lambda.h5", checkpoint=0.5))
    study = study_from_toml(path.read_text())
    summary = run_campaign(study, directory / "lambda.h5")
    assert summary.exit_status == 0
    return study, path, directory / "lambda.h5", summary


def test_a_search_along_lambda_brackets_lambda_c(lambda_searched, tmp_path):
    study, _, output, summary = lambda_searched
    assert study.sweep_keys == ("viscosity_ratio", "shear_rate")
    (search,) = summary.searches
    assert search.point == {"psi_bar": 0.0, "excess_length": 0.94, "B2": study.base.physics.B2, "shear_rate": 40.0}
    assert search.state.status == CONVERGED, search.state.reason
    low, high = search.state.low, search.state.high
    assert 3.0 <= low < high <= 6.0 and high / low - 1 <= 0.6
    assert search.regimes[low] == "TT" and search.regimes[high] == "TU"
    with h5py.File(output, "r") as f:
        assert sorted(f["index/viscosity_ratio"][:]) == sorted(search.regimes)
        assert set(f["index/shear_rate"][:]) == {40.0}
    report = analyze(output, tmp_path / "out", case_figures="none")
    names = {p.name for p in report.written}
    assert {"critical_lambda.csv", "critical_lambda.md"} <= names and "critical_shear.csv" not in names
    with open(tmp_path / "out" / "critical_lambda.csv") as f:
        (row,) = list(csv.DictReader(f))
    assert_estimate(float(row["lambda_C"]), row["lambda_C_from"], search.state) and row["status"] == CONVERGED
    assert float(row["shear_rate"]) == 40.0
    assert "lambda_C" in (tmp_path / "out" / "critical_lambda.md").read_text()


def test_a_search_along_lambda_cut_between_stages_resumes_to_the_same_cases(lambda_searched, tmp_path, monkeypatch):
    study, path, reference, _ = lambda_searched
    output = tmp_path / "lambda.h5"
    stop_before_stage_2(monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        run_campaign(study, output)
    monkeypatch.undo()
    assert run_campaign(study, output, resume=True).exit_status == 0
    assert_same_results(output, reference)


def test_a_search_along_the_shear_rate_keeps_its_fingerprint_when_along_is_said():
    plain = study_from_toml(SEARCH.format(output="x.h5", checkpoint=0.5))
    said = study_from_toml(SEARCH.format(output="x.h5", checkpoint=0.5).replace("[search]\n",
                                                                                  '[search]\nalong = "shear_rate"\n'))
    assert said.search.along == "shear_rate" and said.fingerprint == plain.fingerprint
    with pytest.raises(ConfigError, match="runs along viscosity_ratio: leave viscosity_ratio out of"):
        study_from_toml(LAMBDA_SEARCH.format(output="x.h5", checkpoint=0.5).replace(
            "shear_rate = [40.0]", "viscosity_ratio = [2.0]"))


def test_resuming_a_whole_search_file_leaves_the_file_alone(lambda_searched, tmp_path, caplog):
    """A finished search in today's layout has no half-added stage: --resume must not copy the file to
    drop one (it did, for every search file with blocks, and said it removed 0 cases)."""
    import shutil

    study, _, reference, _ = lambda_searched
    output = tmp_path / "lambda.h5"
    shutil.copyfile(reference, output)
    before = os.stat(output).st_ino
    with caplog.at_level("WARNING"):
        assert run_campaign(study, output, resume=True).exit_status == 0
    assert os.stat(output).st_ino == before
    assert "removed" not in caplog.text
