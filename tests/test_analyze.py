"""hpcves analyze end to end: a tiny campaign -> regimes, tables, figures, results in the file."""
import csv
import math
import subprocess
import sys

import h5py
import numpy as np
import pytest

from conftest import tiny_study
from hpcves.analysis import accuracy
from hpcves.campaign.driver import run_campaign
from hpcves.campaign.study import study_from_toml
from hpcves.config import case_from_toml
from hpcves.files.lock import CampaignLock
from hpcves.reports.analyze import COLUMNS, analyze, read_back
from hpcves.run import runner
from hpcves.run.store import CaseStore


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("analysis")
    output = tmp / "tiny.h5"
    study = study_from_toml(tiny_study(output, t_end=1.0, checkpoint=0.5, psi="[0.0, 0.3]",
                                       extra="[analysis]\nmin_cycles = 4\n"))
    assert study.analysis.min_cycles == 4
    assert run_campaign(study, output).exit_status == 0
    return output


def test_a_tiny_campaign_is_classified_tabulated_drawn_and_stored(campaign, tmp_path):
    report = analyze(campaign, tmp_path / "out")
    rows = {(r["shear_rate"], r["psi_bar"]): r for r in report.rows}
    # psi_bar = 0: no phase pattern, steady inclination (SPEC: about 0.6 rad at Delta = 0.194)
    for S in (40, 80):
        homogeneous = rows[(S, 0.0)]
        assert homogeneous["regime"] == "TT" and "no phase pattern" in homogeneous["reason"]
        assert homogeneous["theta_mean"] == pytest.approx(0.59, abs=0.03)
    # psi_bar = 0.3: tank-treads at S = 40, phase-treads at S = 80 with the solver's period
    assert rows[(40, 0.3)]["regime"] == "TT"
    pt = rows[(80, 0.3)]
    assert pt["regime"] == "PT" and pt["theta_min"] > 0
    assert pt["period"] == pytest.approx(0.1733, rel=0.03)      # N = 128 value; N = 32 is 2.5 % longer
    assert pt["period_err"] < 0.005 * pt["period"]
    assert pt["cycles"] >= 4                                       # the study's [analysis] min_cycles

    out = tmp_path / "out"
    with open(out / "regimes.csv") as f:
        table = list(csv.DictReader(f))
    assert tuple(table[0]) == COLUMNS and len(table) == 4
    assert {"case", "shear_rate", "psi_bar", "excess_length", "B2", "regime", "period", "period_err",
            "theta_mean", "theta_min", "theta_amplitude", "t_settle"} <= set(table[0])
    assert "| 0003 |" in (out / "regimes.md").read_text()
    periods = (out / "periods.md").read_text()
    assert "TT" in periods and f"{pt['period']:.4g} +-" in periods
    # a fixed-step campaign: the discretisation error is not estimated, and the tables say so
    assert np.isnan(pt["period_dt_err"]) and np.isnan(pt["theta_mean_dt_err"]) and np.isnan(pt["rtol"])
    error, tag = accuracy.error_bar(pt, "period")
    assert "dt n/e" in tag
    assert f"{pt['period']:.4g} +- {error:.1g} [{tag}]" in periods
    assert "| n/e |" in (out / "regimes.md").read_text()
    for name in ("phase_diagram", "periods", "intrinsic_viscosity", "normal_stress"):
        for ext in ("png", "pdf"):
            assert (out / f"{name}.{ext}").stat().st_size > 1000
    assert sorted(p.name for p in (out / "cases").iterdir()) == [f"000{i}.png" for i in range(4)]
    # the stress the vesicles add: settled means near the rigid disk's [eta] = 2 for this near-circle,
    # each with its statistical bar, a phase-treading case's [eta] oscillating with theta
    for row in report.rows:
        assert 1.5 < row["intrinsic_viscosity"] < 2.0 and 0.5 < row["normal_stress_coefficient"] < 1.5, row
        assert 0 <= row["intrinsic_viscosity_err"] < 1e-3 * row["intrinsic_viscosity"]
    assert pt["intrinsic_viscosity_amplitude"] > 10 * rows[(40, 0.3)]["intrinsic_viscosity_amplitude"]
    assert "[eta]" in (out / "regimes.md").read_text()

    assert report.wrote_back
    stored = read_back(campaign)
    assert [r["regime"] for r in stored] == [r["regime"] for r in report.rows]
    assert np.allclose([r["period"] for r in stored], [r["period"] for r in report.rows], equal_nan=True)


def test_overrides_change_the_verdict(campaign, tmp_path):
    strict = analyze(campaign, tmp_path, overrides={"min_cycles": 50.0}, write_to_file=False, case_figures=False)
    pt = next(r for r in strict.rows if r["shear_rate"] == 80 and r["psi_bar"] == 0.3)
    assert pt["regime"] == "undecided" and "run longer" in pt["reason"]


def test_a_running_campaign_is_analyzed_but_not_written_to(campaign, tmp_path):
    lock = CampaignLock(campaign).acquire()
    try:
        report = analyze(campaign, tmp_path, case_figures=False)
    finally:
        lock.release()
    assert not report.wrote_back and "is writing this file" in report.note
    assert (tmp_path / "regimes.csv").exists()


def test_a_single_adaptive_run_is_analyzed_with_discretisation_error_bars(tmp_path):
    case = case_from_toml("[numerics]\nN = 32\nrtol = 3e-2\n[physics]\nshear_rate = 80.0\npsi_bar = 0.3\n"
                          "[run]\nmax_spectral_tail = 1.0\nt_end = 1.0\nsample_interval = 0.005\n")
    path = tmp_path / "single.h5"
    with h5py.File(path, "w") as h5:
        store = CaseStore.create(h5, case)
        runner.run(store, h5.flush)
    report = analyze(path, tmp_path / "out", case_figures=False)
    [row] = report.rows
    assert row["regime"] == "PT" and report.wrote_back and row["rtol"] == 3e-2
    # the rule of accuracy.py, from the rtol the file records
    assert row["period_dt_err"] == pytest.approx(accuracy.PERIOD_PER_RTOL * 3e-2 * row["period"])
    assert row["theta_mean_dt_err"] == pytest.approx(accuracy.INCLINATION_PER_RTOL * 3e-2)
    assert 0 < row["theta_mean_err"] < row["theta_amplitude"]
    error, dominant = accuracy.error_bar(row, "period")
    # N = 32 with the watch off: a tail (1e-2) beyond what the spatial rule holds at, so no spatial bar
    assert np.isnan(row["period_N_err"]) and np.isnan(row["theta_mean_N_err"])
    assert error == pytest.approx(row["period_err"] + row["period_dt_err"])
    assert dominant == ("dt" if row["period_dt_err"] >= row["period_err"] else "stat") + ", N n/e"
    table = (tmp_path / "out" / "regimes.md").read_text()
    assert f"| {row['period_dt_err']:.2g} |" in table and "+- dt" in table
    stored = read_back(path)
    assert stored[0]["period_dt_err"] == pytest.approx(row["period_dt_err"])


def test_the_command_line_reports_and_refuses_bad_options(campaign, tmp_path):
    command = [sys.executable, "-m", "hpcves.cli", "analyze", str(campaign), "--out", str(tmp_path),
               "--no-case-figures"]
    result = subprocess.run(command, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "4 cases: " in result.stdout and "PT" in result.stdout
    for bad, words in ((["--set", "mincycles=3"], "unknown key mincycles"),
                       (["--set", "min_cycles"], "use key=value"),
                       (["--axes", "shear_rate"], "give two parameters")):
        result = subprocess.run(command + bad, capture_output=True, text=True)
        assert result.returncode == 2 and words in result.stderr and "Traceback" not in result.stderr
    missing = subprocess.run(command[:4] + [str(tmp_path / "nope.h5")], capture_output=True, text=True)
    assert missing.returncode == 2 and "no such file" in missing.stderr


def test_error_bars_say_which_part_dominates_and_tumbling_gets_none():
    pt = {"period": 0.1, "period_err": 1e-6, "period_dt_err": accuracy.period_error(0.1, 1e-2)}
    assert pt["period_dt_err"] == pytest.approx(accuracy.PERIOD_PER_RTOL * 1e-3)
    assert accuracy.error_bar(pt, "period") == (pytest.approx(1e-6 + pt["period_dt_err"]), "dt, N n/e")
    noisy = {**pt, "period_err": 1.0}
    assert accuracy.error_bar(noisy, "period")[1] == "stat, N n/e"
    # the grid's part: in proportion to the largest spectral tail over the settled record
    t = np.linspace(0.0, 10.0, 11)
    tail_theta, tail_psi = np.full(11, 1e-6), np.full(11, 2e-6)
    tail_theta[2] = 5e-3                                   # before t_settle = 3: the start-up, not counted
    tail_psi[8] = 4e-5
    assert accuracy.settled_tail(t, tail_theta, tail_psi, 3.0) == 4e-5
    assert accuracy.settled_tail(t, tail_theta, None, math.nan) == 5e-3      # no settling known: all of it
    assert np.isnan(accuracy.settled_tail(t, None, None, 3.0))               # a file from before the tails
    coarse = {**pt, "period_N_err": accuracy.spatial_period_error(0.1, 2e-3)}
    assert coarse["period_N_err"] == pytest.approx(accuracy.PERIOD_PER_TAIL * 2e-4)
    assert np.isnan(accuracy.spatial_period_error(0.1, 1e-2))              # beyond the watch: not estimated
    assert accuracy.error_bar(coarse, "period") == (pytest.approx(1e-6 + pt["period_dt_err"] + coarse["period_N_err"]),
                                                    "N" if coarse["period_N_err"] > pt["period_dt_err"] else "dt")
    assert accuracy.spatial_inclination_error(0.3, 1e-4) == pytest.approx(accuracy.INCLINATION_PER_TAIL * 1e-4)
    assert np.isnan(accuracy.spatial_period_error(7.1, 1e-3, flips=True))
    assert np.isnan(accuracy.period_error(7.1, 1e-2, flips=True))          # tumbling: no rule
    assert np.isnan(accuracy.inclination_error(0.1, 1e-2, flips=True))
    assert np.isnan(accuracy.period_error(0.1, None))                       # a fixed step: none
    assert accuracy.error_bar({"period_err": 1e-6, "period_dt_err": np.nan}, "period") == (1e-6, "stat, dt n/e, N n/e")


def test_shape_sequences_and_an_animation_are_drawn_from_a_campaign(campaign, tmp_path):
    from click.testing import CliRunner
    from PIL import Image

    from hpcves.cli import main
    from hpcves.reports import figures

    def hpcves(*args):                    # in this process: the import of a subprocess costs ~1.5 s a call
        result = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=True)
        assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
        result.returncode = result.exit_code
        return result

    chosen = figures.choose(campaign, where={"psi_bar": 0.3})
    assert [c.parameters["shear_rate"] for c in chosen] == [40.0, 80.0]
    fig = figures.shape_sequence_figure(chosen, n_shapes=4)
    assert fig._suptitle.get_text() == r"$\bar\psi$ = 0.3, $\Delta$ = 0.193853, $B_2$ = 0.1"
    titles = [ax.get_title(loc="left") for ax in fig.axes if ax.get_title(loc="left")]
    assert titles[0].startswith("S = 40: ") and titles[1].startswith("S = 80: ")
    result = hpcves("shapes", campaign, "--where", "psi_bar=0.3", "--out", tmp_path / "s.png", "--shapes", "3",
                    "--no-streamlines")                          # (drawn with them above)
    assert result.returncode == 0, result.stderr
    assert "2 rows" in result.stdout and Image.open(tmp_path / "s.png").size[0] > 500
    movie = tmp_path / "m.gif"
    result = hpcves("animate", campaign, "--case", "0001", "--out", movie, "--no-streamlines", "--fps", "5")
    assert result.returncode == 0, result.stderr
    assert Image.open(movie).n_frames == 21 and not (tmp_path / "m.gif.partial.gif").exists()
    for args, words in ((("shapes", campaign, "--case", "9999"), "no case 9999"),
                        (("shapes", campaign, "--where", "psi=0.3"), "PARAMETER one of"),
                        (("shapes", campaign), "choose the cases"),
                        (("shapes", campaign, "--where", "psi_bar=0.7"), "no case has psi_bar = 0.7"),
                        (("animate", campaign), "name the case with --case"),
                        (("animate", campaign, "--case", "0001", "--out", tmp_path / "m.avi"), ".mp4 (ffmpeg) or")):
        result = hpcves(*args)
        assert result.returncode == 2 and words in result.stderr and "Traceback" not in result.stderr, result.stderr
    from matplotlib import animation
    if not animation.writers.is_available("ffmpeg"):
        result = hpcves("animate", campaign, "--case", "0001", "--out", tmp_path / "m.mp4")
        assert result.returncode == 2 and "needs ffmpeg" in result.stderr


def test_case_pages_are_drawn_for_the_cases_asked_for_and_alike_in_parallel(campaign, tmp_path):
    from PIL import Image

    from hpcves.model.params import ConfigError
    from hpcves.reports import case_pages

    rows = [{"case": "0000", "status": "finished", "regime": "TT"},
            {"case": "0001", "status": "finished", "regime": "undecided"},
            {"case": "0002", "status": "failed", "regime": "failed"},
            {"case": "0003", "status": "running", "regime": "PT"}]
    assert [r["case"] for r in case_pages.chosen(rows, "flagged")] == ["0001", "0002", "0003"]
    assert [r["case"] for r in case_pages.chosen(rows, ["0003", "0000"])] == ["0000", "0003"]
    assert case_pages.chosen(rows, "none") == [] and len(case_pages.chosen(rows, "all")) == 4
    assert case_pages.chosen(rows, "auto") == case_pages.chosen(rows, "all")          # a few cases: every page
    many = [dict(rows[i % len(rows)], case=f"{i:04d}") for i in range(case_pages.AUTO_PAGES + 1)]
    auto = case_pages.chosen(many, "auto")                   # many: the flagged ones', at most AUTO_PAGES
    assert auto == [r for r in many if case_pages.flagged(r)][:case_pages.AUTO_PAGES] and len(auto) < len(many)
    for which, words in (("flaged", "none of auto, all, flagged, none"), (["0007"], "no case 0007")):
        with pytest.raises(ConfigError, match=words):
            case_pages.chosen(rows, which)
    with pytest.raises(ConfigError, match="no case 0009"):         # refused before any work
        analyze(campaign, tmp_path / "refused", write_to_file=False, case_figures=["0009"])
    assert not (tmp_path / "refused").exists()

    serial = analyze(campaign, tmp_path / "serial", write_to_file=False, case_figures=["0001", "0003"],
                     streamlines=False)
    pooled = analyze(campaign, tmp_path / "pooled", write_to_file=False, case_figures=["0001", "0003"],
                     streamlines=False, jobs=2)
    for report, out in ((serial, tmp_path / "serial"), (pooled, tmp_path / "pooled")):
        assert sorted(p.name for p in (out / "cases").iterdir()) == ["0001.png", "0003.png"]
        assert any(str(p).endswith("<case>.png (2)") for p in report.written)
    for name in ("0001.png", "0003.png"):          # two processes draw the same pixels as one
        one, two = (np.asarray(Image.open(tmp_path / d / "cases" / name)) for d in ("serial", "pooled"))
        assert one.shape == two.shape and one.shape[0] > 500 and np.array_equal(one, two)
    analyze(campaign, tmp_path / "none", write_to_file=False, case_figures=False)
    assert (tmp_path / "none" / "regimes.csv").read_bytes() == (tmp_path / "serial" / "regimes.csv").read_bytes()
    assert not (tmp_path / "none" / "cases").exists()


def test_the_overview_script_draws_every_case_of_a_campaign(campaign, tmp_path):
    """analysis/plot_campaign.py (make demo's last step) reads a campaign of the current layout, whose
    cases are rows of blocks with no group of their own, and draws the overview and one page a case."""
    from pathlib import Path

    script = Path(__file__).resolve().parent.parent / "analysis" / "plot_campaign.py"
    out = subprocess.run([sys.executable, str(script), str(campaign), "--out", str(tmp_path / "overview.png"),
                          "--cases", str(tmp_path / "cases")], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    with h5py.File(campaign, "r") as f:
        assert "blocks" in f
        n = int(f.attrs["n_cases"])
    pages = sorted(p.name for p in (tmp_path / "cases").glob("*.png"))
    assert (tmp_path / "overview.png").stat().st_size > 10_000 and len(pages) == n == 4
