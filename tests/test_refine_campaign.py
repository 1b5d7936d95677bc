"""The [refine] campaign mode: regime boundaries refined by the campaign runner, end to end.

Tiny real cases (N = 32, t_end = 1.5) over S in [30, 120] x psi_bar in [0, 0.3]
at Delta = 0.194: the homogeneous vesicle tank-treads everywhere, psi_bar = 0.3
goes from TT to PT between S = 60 and 85 (test_search_campaign.py finds S_C
there), so the coarse 2 x 2 grid has one mixed cell. Two refinements (B2 = 0.1, 0.2).
"""
import csv
import os
import shutil
import signal

import h5py
import numpy as np
import pytest

from conftest import TINY_RUN
from hpcves.analysis.refine import CONVERGED, polylines
from hpcves.campaign.driver import run_campaign
from hpcves.campaign.study import study_from_toml
from hpcves.errors import FileFormatError
from hpcves.model.params import ConfigError
from hpcves.reports.analyze import analyze
from hpcves.reports.datasets import open_campaign
from hpcves.run.store import FINISHED
from jobs import TEN_STEPS, assert_same_results, case_view, case_views, hpcves, job_pids, start_job, wait_until
from test_campaign import needs_mpi, statuses

REFINE = """
[campaign]
name = "refine"
output = "{output}"
t_end = 1.5
""" + TINY_RUN + """[sweep]
shear_rate = [30.0, 120.0]
psi_bar = [0.0, 0.3]
B2 = [0.1, 0.2]
[refine]
tolerance = {{ shear_rate = 0.5, psi_bar = 0.15 }}
max_cases = 30
"""


def write_refine(tmp_path, checkpoint=0.5):
    output = tmp_path / "refine.h5"
    path = tmp_path / "refine.toml"
    path.write_text(REFINE.format(output=output, checkpoint=checkpoint))
    return path, output


@pytest.fixture(scope="module")
def refined(tmp_path_factory):
    """The tiny refinement run serially in this process: (study, file, summary, outcomes of every stage)."""
    path, output = write_refine(tmp_path_factory.mktemp("refine"))
    study = study_from_toml(path.read_text())
    stages = []
    summary = run_campaign(study, output, on_stage=stages.append)
    assert summary.exit_status == 0
    return study, output, summary, stages


def test_a_refine_study_has_one_refinement_per_other_swept_value():
    study = study_from_toml(REFINE.format(output="x.h5", checkpoint=0.5))
    assert study.mode == "refine" and study.staged and study.cases == ()
    assert study.refine.axes == ("shear_rate", "psi_bar")
    assert study.refinements == ({"B2": 0.1}, {"B2": 0.2})
    settings = study.refine_settings
    assert settings.x.log and not settings.y.log and settings.max_cases == 30
    case = study.refine_case(1, 60.0, 0.15, "0007")
    assert case.swept == {"shear_rate": 60.0, "psi_bar": 0.15, "B2": 0.2} and case.search == 1
    assert case.case.physics.B2 == 0.2 and case.case.run.t_end == 1.5
    # the fingerprint covers what decides the cases: a tolerance changes it, a comment does not
    same = study_from_toml("# a comment\n" + REFINE.format(output="x.h5", checkpoint=0.5))
    other = study_from_toml(REFINE.format(output="x.h5", checkpoint=0.5).replace("psi_bar = 0.15", "psi_bar = 0.1"))
    assert same.fingerprint == study.fingerprint != other.fingerprint


def test_the_refinements_bracket_the_transition_to_the_tolerances(refined):
    study, output, summary, stages = refined
    assert len(summary.searches) == 2
    for outcome in summary.searches:
        assert outcome.state.status == CONVERGED, outcome.state.reason
        regimes = outcome.regimes
        assert set(regimes[(s, 0.0)] for s in (30.0, 120.0)) == {"TT"}         # homogeneous: TT everywhere
        assert regimes[(30.0, 0.3)] == "TT" and regimes[(120.0, 0.3)] == "PT"
        assert len(regimes) < outcome.settings.full_grid_cases()
        lines = polylines(outcome.settings, regimes, outcome.state.cells)
        assert [pair for pair, _ in lines] == ["PT|TT"]
        for crossing in lines[0][1]:             # each crossing between a TT and a PT case, within the tolerances
            ends = {regimes[(crossing.x_low, crossing.y_low)], regimes[(crossing.x_high, crossing.y_high)]}
            assert ends == {"TT", "PT"} and not crossing.blurry
            assert crossing.x_high / crossing.x_low <= 1.5 + 1e-9 and crossing.y_high - crossing.y_low <= 0.15 + 1e-9
    # B2 = 0.1 at psi_bar = 0.3: TT at 60, PT at 84.85 (the search's S_C lies in between)
    first = summary.searches[0].regimes
    assert first[(60.0, 0.3)] == "TT" and first[(84.8528137424, 0.3)] == "PT"
    assert summary.searches == tuple(stages[-1])
    assert [sum(len(o.regimes) for o in s) for s in stages][:2] == [0, 8]   # the two coarse grids first


def test_the_file_holds_every_case_with_its_refinement(refined):
    study, output, summary, _ = refined
    n = sum(len(o.regimes) for o in summary.searches)
    with h5py.File(output, "r") as f:
        assert f.attrs["mode"] == "refine" and f.attrs["n_cases"] == n == len(case_views(f))
        assert list(f["refinements/B2"][:]) == [0.1, 0.2]
        assert list(f["index/search"][:8]) == [0, 0, 0, 0, 1, 1, 1, 1]
        for i, refinement in enumerate(f["index/search"][:]):
            g = case_view(f, f"{i:04d}")
            assert g.attrs["physics.B2"] == [0.1, 0.2][refinement]
            assert g.attrs["physics.shear_rate"] == f["index/shear_rate"][i]
            assert g.attrs["physics.psi_bar"] == f["index/psi_bar"][i]
    assert set(statuses(output).values()) == {FINISHED}


def test_a_finished_refinement_resumed_runs_nothing_and_replays_the_same_verdicts(refined, tmp_path):
    study, output, summary, _ = refined
    again = run_campaign(study, output, resume=True)
    assert again.ran == () and again.exit_status == 0
    assert [(o.state.status, o.regimes) for o in again.searches] == \
        [(o.state.status, o.regimes) for o in summary.searches]


def test_every_verdict_is_kept_in_the_file_and_a_replay_classifies_nothing(refined, tmp_path, monkeypatch):
    """A case is classified once: its verdict is in index/verdict with the wall seconds it had then, and
    ``status`` (a replay of the refinement) and a resume take it from there. A case whose wall seconds
    differ (run again) is classified again; verdicts another classifier stored are not taken."""
    import shutil

    import hpcves.run.verdict as verdict_module
    from hpcves.campaign.file import read_table
    from hpcves.campaign.progress import progress
    from hpcves.run.verdict import Verdict

    study, output, summary, _ = refined
    copy = tmp_path / "copy.h5"
    shutil.copy(output, copy)
    with h5py.File(copy, "r") as f:
        verdicts, walls = f["index/verdict"][:, 0], f["index/verdict"][:, 1]
        assert (verdicts >= 0).all() and len(verdicts) == f.attrs["n_cases"]
        assert list(walls) == [case_view(f, f"{i:04d}")["progress"][2] for i in range(len(walls))]
    regimes = [Verdict.from_code(c).regime for c in verdicts]
    assert sorted(set(regimes)) == ["PT", "TT"]
    classified = []

    def classify(data, settings):
        classified.append(data.case_id)
        return {"regime": "TU", "reason": ""}

    monkeypatch.setattr(verdict_module, "analyze_case", classify)
    rows = read_table(copy).rows
    assert progress(copy, rows, None).complete and classified == []
    again = run_campaign(study, copy, resume=True)
    assert classified == [] and [o.regimes for o in again.searches] == [o.regimes for o in summary.searches]
    with h5py.File(copy, "r+") as f:
        case = case_view(f, "0002")
        case["progress"] = case["progress"] + [0, 0, 1.0, 0]           # as if it had run again
    assert progress(copy, read_table(copy).rows, None) is not None and classified == ["0002"]
    with h5py.File(copy, "r+") as f:
        f["index/verdict"].attrs["classifier"] = "another"
    progress(copy, read_table(copy).rows, None)
    assert len(classified) == 1 + len(regimes)


def stored_codes(output) -> list[int]:
    with h5py.File(output, "r") as f:
        return [int(c) for c in f["index/verdict"][:, 0]]


def classified_again(output) -> list[int]:
    """Every case of the file read and classified again, as rank 0 would between stages."""
    from hpcves.campaign.file import CampaignFile
    from hpcves.run.verdict import case_data, verdict_of

    study = study_from_toml(REFINE.format(output=output, checkpoint=0.5))
    with h5py.File(output, "r") as f:
        campaign = CampaignFile(f)
        return [verdict_of(case_data(campaign.store(c), c), study.analysis)[0].code for c in campaign.case_ids]


def test_the_rank_that_ran_a_case_classifies_it_and_rank_0_classifies_nothing(tmp_path, monkeypatch):
    """A staged study's case is classified where it ran, right after it ended (scheduler._verdict); the
    stage driver takes that verdict and reads no case between stages. The verdicts are rank 0's."""
    import hpcves.campaign.scheduler as scheduler
    import hpcves.campaign.search_stages as stages

    where = {"ran": 0, "between stages": 0}

    def counted(name, real):
        def call(*args):
            where[name] += 1
            return real(*args)
        return call

    monkeypatch.setattr(scheduler, "verdict_of", counted("ran", scheduler.verdict_of))
    monkeypatch.setattr(stages, "verdict_of", counted("between stages", stages.verdict_of))
    path, output = write_refine(tmp_path)
    text = path.read_text().replace("B2 = [0.1, 0.2]", "B2 = [0.1]")
    assert run_campaign(study_from_toml(text), output).exit_status == 0
    codes = stored_codes(output)
    assert where == {"ran": len(codes), "between stages": 0} and len(codes) > 4
    assert codes == classified_again(output)


@needs_mpi
def test_under_relay_a_worker_classifies_its_case_from_data_rank_0_reads_for_it(refined, tmp_path):
    """--io relay: the worker asks rank 0 for its ended case's data (relay read "case_data") and
    classifies it; the verdicts stored are rank 0's, and the refinement is the serial one."""
    _, _, summary, _ = refined
    path, output = write_refine(tmp_path)
    path.write_text(path.read_text().replace("B2 = [0.1, 0.2]", "B2 = [0.1]"))
    result = hpcves("campaign", path, "--quiet", "--io", "relay", n=2)
    from hpcves.run.verdict import Verdict

    assert result.returncode == 0, result.stderr
    assert "not classified where it ran" not in result.stderr
    codes = stored_codes(output)
    assert codes == classified_again(output) and min(codes) >= 0
    with h5py.File(output, "r") as f:
        points = zip(f["index/shear_rate"][:], f["index/psi_bar"][:], codes)
        assert {(x, y): Verdict.from_code(c).regime for x, y, c in points} == summary.searches[0].regimes


def test_verdict_codes_name_every_regime_and_reason_to_run_again():
    from hpcves.run.verdict import VERDICT_REGIMES, Verdict

    for regime in VERDICT_REGIMES:
        for under, crept, unsettled in ((False, False, False), (True, False, False), (False, True, False),
                                        (False, False, True)):
            verdict = Verdict(regime, under, crept, unsettled)
            assert Verdict.from_code(verdict.code) == verdict
    assert Verdict("PT+TT").code == -1
    assert [Verdict.from_code(c) for c in (-1.0, float("nan"), 1.5, 8 * len(VERDICT_REGIMES))] == [None] * 4


def test_a_refinement_grows_by_a_new_value_of_a_key_that_is_not_an_axis(refined, tmp_path):
    """B2 = 0.15 put before 0.1, 0.2: a third refinement, numbered after the file's two, which keep their
    cases bit for bit; the same study resumed again (sweep order unlike the file's) runs nothing."""
    from jobs import _same, results

    study, reference, summary, _ = refined
    output = tmp_path / "refine.h5"
    shutil.copy(reference, output)
    text = study.source.replace("B2 = [0.1, 0.2]", "B2 = [0.15, 0.1, 0.2]").replace(str(reference), str(output))
    grown = study_from_toml(text)
    said = []
    again = run_campaign(grown, output, resume=True, announce=lambda line, *_: said.append(line))
    assert again.exit_status == 0 and again.ran
    assert any("the study grew: 1 new refinement (B2 += 0.15)" in line for line in said), said
    before, after = results(reference), results(output)
    assert all(_same(before[c], after[c]) for c in before if c.startswith("0"))
    with h5py.File(output, "r") as f:
        assert list(f["refinements/B2"][:]) == [0.1, 0.2, 0.15]
        assert set(f["index/search"][len(summary.ran):]) == {2}
    old = {o.point["B2"]: o.regimes for o in summary.searches}
    assert [o.point["B2"] for o in again.searches] == [0.1, 0.2, 0.15]
    assert all(o.regimes == old[o.point["B2"]] for o in again.searches[:2])
    assert again.searches[2].state.status == CONVERGED
    said.clear()
    once_more = run_campaign(grown, output, resume=True, announce=lambda line, *_: said.append(line))
    assert once_more.ran == () and not any("grew" in line for line in said)
    assert [o.point["B2"] for o in once_more.searches] == [0.1, 0.2, 0.15]
    coarser = study_from_toml(text.replace("shear_rate = [30.0, 120.0]", "shear_rate = [20.0, 120.0]"))
    with pytest.raises(FileFormatError, match=r"its axes' values, the coarse grid \(shear_rate"):
        run_campaign(coarser, output, resume=True)


def test_the_datatree_of_a_refine_file_holds_its_refinements_and_boundaries(refined, tmp_path):
    """open_campaign(tree=True) of an analysed refine file: refinement.csv and boundaries.csv as Datasets."""
    _, reference, summary, _ = refined
    output = tmp_path / "refine.h5"
    shutil.copy(reference, output)
    analyze(output, tmp_path / "analysis", case_figures=False)
    tree = open_campaign(output, tree=True)
    assert set(tree.children) == {"cases", "analysis", "refinement"}
    table = tree["refinement"].to_dataset(inherit=False)
    assert list(table["status"].values) == ["converged", "converged"]
    assert list(table["cases"].values) == [len(o.regimes) for o in summary.searches]
    lines = tree["refinement/boundaries"].to_dataset(inherit=False)
    with open(tmp_path / "analysis" / "boundaries.csv") as f:
        rows = list(csv.DictReader(f))
    assert lines.sizes["point"] == len(rows) > 0
    assert np.allclose(lines["shear_rate"].values, [float(r["shear_rate"]) for r in rows])
    assert set(lines["pair"].values) == {"PT|TT"}


def test_analyze_writes_the_boundaries_as_polylines_on_the_phase_diagram(refined, tmp_path):
    study, output, summary, _ = refined
    report = analyze(output, tmp_path, write_to_file=False, case_figures=False)
    with open(tmp_path / "boundaries.csv") as f:
        lines = list(csv.DictReader(f))
    assert list(lines[0]) == ["B2", "line", "pair", "order", "shear_rate", "psi_bar", "shear_rate_low",
                              "shear_rate_high", "psi_bar_low", "psi_bar_high", "blurry"]
    for outcome in summary.searches:
        mine = [r for r in lines if float(r["B2"]) == outcome.point["B2"]]
        expected = polylines(outcome.settings, outcome.regimes, outcome.state.cells)
        assert len(mine) == sum(len(c) for _, c in expected)
        assert {r["pair"] for r in mine} == {"PT|TT"} and {r["blurry"] for r in mine} == {"0"}
        for r in mine:
            assert float(r["shear_rate_low"]) <= float(r["shear_rate"]) <= float(r["shear_rate_high"])
    with open(tmp_path / "refinement.csv") as f:
        table = list(csv.DictReader(f))
    assert [r["status"] for r in table] == ["converged", "converged"]
    assert [int(r["cases"]) for r in table] == [len(o.regimes) for o in summary.searches]
    assert [r["status"] for r in report.refinements] == ["converged", "converged"]
    assert "Regime boundaries of 'refine'" in (tmp_path / "refinement.md").read_text()
    for b2 in ("0.1", "0.2"):
        assert (tmp_path / f"phase_diagram_B2{b2}.png").stat().st_size > 1000
    assert not (tmp_path / "periods.md").exists()            # irregular points: no period table


@pytest.mark.parametrize("table, message", [
    ("[refine]\naxes = [\"shear_rate\", \"B2\"]\n", "axis B2 is not in \\[sweep\\]"),
    ("[refine]\naxes = [\"shear_rate\"]\n", "give the two swept parameters"),
    ("[refine]\ntolerance = { shear_rate = -0.1 }\n", "tolerance.shear_rate = -0.1: must be > 0"),
    ("[refine]\ntolerance = { B2 = 0.1 }\n", "tolerance for B2, which is not an axis"),
    ("[refine]\nmax_cases = 3\n", "fewer than the 4 points of the coarse grid"),
    ("[refine]\nbudget = 3\n", "unknown key budget"),
    ("[refine]\nstraight_span = 0.5\n", "straight_span = 0.5: must be >= 1"),
    ("[refine]\nstraight_span = \"long\"\n", "straight_span"),
    ("[refine]\n[search]\nlow = 1.0\nhigh = 2.0\n", "give one"),
])
def test_bad_refine_tables_are_refused(table, message):
    with pytest.raises(ConfigError, match=message):
        study_from_toml("[sweep]\nshear_rate = [10.0, 100.0]\npsi_bar = [0.3, 0.5]\n" + table)


def test_the_straight_span_is_part_of_the_fingerprint_and_1_is_that_of_files_from_before_it():
    base = "[sweep]\nshear_rate = [10.0, 100.0]\npsi_bar = [0.3, 0.5]\n[refine]\n"
    default, quadtree, same = (study_from_toml(base + extra).fingerprint
                               for extra in ("", "straight_span = 1\n", "straight_span = 4\n"))
    assert default == same and default != quadtree
    # what the version before the key (a quadtree) wrote for this study: such files resume with 1
    assert quadtree == "1c9577def711829504cb056c9951399787ffbcc8cf99f82e34db4b3801baed90"


def test_a_refine_axis_with_one_value_is_refused():
    with pytest.raises(ConfigError, match="axis psi_bar has 1 value"):
        study_from_toml("[sweep]\nshear_rate = [10.0, 100.0]\npsi_bar = 0.3\nB2 = [0.1, 0.2]\n"
                        "[refine]\naxes = [\"shear_rate\", \"psi_bar\"]\n")


@needs_mpi
def test_mpi_refinement_killed_in_a_later_stage_resumes_to_the_serial_result(refined, tmp_path):
    """SIGKILL once the second stage runs, resume on two ranks: every case bitwise as in the serial run."""
    _, reference, summary, _ = refined
    path, output = write_refine(tmp_path, checkpoint=0.05)
    job = start_job(2, "campaign", path, "--quiet")

    def second_stage_runs():            # the file is always whole (atomic.py): read it as it is
        assert job.poll() is None, job.communicate()
        if not output.exists():
            return False
        with h5py.File(output, "r", locking=False) as f:
            return f.attrs["n_cases"] > 8 and any(int(g["status"][()]) == 1 for _, g in case_views(f))
    wait_until(second_stage_runs, "the refinement's second stage runs")
    for pid in job_pids(job.pid):
        os.kill(pid, signal.SIGKILL)
    job.communicate()
    result = hpcves("campaign", path, "--resume", n=2)
    assert result.returncode == 0, result.stderr
    assert_same_results(output, reference, attrs=False)        # checkpointed 10 times as often
    # the verdicts the ranks that ran the cases sent (or rank 0 found on resuming) are the serial run's
    assert stored_codes(output) == stored_codes(reference) == classified_again(output)
    with open(tmp_path / "refine_refinement.csv") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["cases"]) for r in rows] == [len(o.regimes) for o in summary.searches]
    assert "converged" in result.stdout


def test_a_refinement_out_of_budget_continues_when_the_budget_is_raised(refined, tmp_path):
    """max_cases is left out of the fingerprint: a refinement that spent its budget, resumed with a
    larger one, finishes with the points and verdicts of one that had the larger budget from the start
    (the B2 = 0.1 refinement alone: its cases are those of the fixture's first refinement)."""
    _, _, summary, _ = refined
    output = tmp_path / "refine.h5"
    text = REFINE.format(output=output, checkpoint=0.5).replace("B2 = [0.1, 0.2]", "B2 = [0.1]")
    small = text.replace("max_cases = 30", "max_cases = 9")
    first = run_campaign(study_from_toml(small), output)
    assert [o.state.status for o in first.searches] == ["budget spent"]
    assert len(first.searches[0].regimes) <= 9
    large = study_from_toml(text)
    assert large.fingerprint == study_from_toml(small).fingerprint
    again = run_campaign(large, output, resume=True)
    assert [(o.state.status, o.regimes) for o in again.searches] == \
        [(o.state.status, o.regimes) for o in summary.searches[:1]]
    with h5py.File(output, "r") as f:           # the stored text is the one that made the last stage
        assert "max_cases = 30" in f.attrs["campaign_toml"]
    report = analyze(output, tmp_path / "analysis", write_to_file=False, case_figures=False)
    assert [r["status"] for r in report.refinements] == ["converged"]


@needs_mpi
def test_a_point_the_model_refuses_ends_an_mpi_refinement_in_one_line_not_a_hang(tmp_path):
    """psi_bar = 0.925 (asked for in the second stage, between 0.85 and 1) starts psi outside its allowed
    range: a ConfigError on rank 0 while it made the next stage. The other ranks waited for the plan
    for ever (the job hung in its final collective close); now every rank ends with it, exit 2."""
    path = tmp_path / "refuse.toml"
    path.write_text(f"""[campaign]
name = "refuse"
output = "{tmp_path / 'refuse.h5'}"
""" + TEN_STEPS + """[sweep]
shear_rate = [1.0, 100.0]
psi_bar = [0.85, 1.0]
[refine]
tolerance = { shear_rate = 0.5, psi_bar = 0.02 }
max_cases = 20
""")
    result = hpcves("campaign", path, "--quiet", n=2)
    errors = [line for line in result.stderr.splitlines() if line.startswith("Error:")]
    assert result.returncode == 2 and len(errors) == 1, result.stderr
    assert "psi_bar = 0.925" in errors[0] and "outside the allowed range" in errors[0]
