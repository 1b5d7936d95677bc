"""Starts as a study dimension: [starts] names starts, every point runs from each, and the analysis
groups each point's runs into attractors."""
import dataclasses

import pytest

from hpcves.campaign.driver import run_campaign
from hpcves.campaign.study import study_from_toml
from hpcves.model.params import ConfigError

STUDY = """
[campaign]
name = "starts"
output = "{output}"
t_end = 3.0
[numerics]
N = 32
dt = 1e-3
[run]
max_spectral_tail = 1.0          # N = 32 on purpose (fast)
until_decided = true
sample_interval = 0.005
snapshot_interval = 0.05
[sweep]
psi_bar = 0.3
shear_rate = [10, 20]
[starts]
published = {{}}
two_domains = {{ initial_phase = "domains", phase_domains = 2, delta = 0.16 }}
"""


def study_text(tmp_path, starts=None):
    text = STUDY.format(output=tmp_path / "starts.h5")
    if starts is not None:
        text = text.split("[starts]")[0] + "[starts]\n" + starts + "\n"
    return text


def test_every_point_runs_from_every_start_in_the_order_given(tmp_path):
    study = study_from_toml(study_text(tmp_path))
    assert study.sweep_keys == ("psi_bar", "shear_rate", "start")
    got = [(c.swept["shear_rate"], c.swept["start"], c.case.physics.initial_phase, c.case.physics.phase_domains,
            c.case.physics.delta) for c in study.cases]
    assert got == [(10, 0, "published", 1, 0.05), (10, 1, "domains", 2, 0.16),
                   (20, 0, "published", 1, 0.05), (20, 1, "domains", 2, 0.16)]
    # another start is another study
    other = study_from_toml(study_text(tmp_path, 'published = {}\ntwo_domains = { initial_phase = "domains", '
                                                 'phase_domains = 2, delta = 0.2 }'))
    assert other.fingerprint != study.fingerprint


def test_starts_change_the_fingerprint_of_a_refinement_too(tmp_path):
    refine = '[refine]\naxes = ["shear_rate", "psi_bar"]\ntolerance = { shear_rate = 0.5, psi_bar = 0.1 }\n'
    text = study_text(tmp_path).replace("psi_bar = 0.3", "psi_bar = [0.3, 0.5]") + refine
    study = study_from_toml(text)
    assert study.refinements == ({"start": 0.0}, {"start": 1.0})
    changed = study_from_toml(text.replace("delta = 0.16", "delta = 0.2"))
    assert changed.fingerprint != study.fingerprint


@pytest.mark.parametrize("starts, message", [
    ('ellipse = { shear_rate = 3 }', "unknown key shear_rate"),
    ('ellipse = 3', "must be a table"),
    ('bad = { initial_phase = "stripes" }', "starts.bad: physics.initial_phase"),
])
def test_bad_starts_are_refused(tmp_path, starts, message):
    with pytest.raises(ConfigError, match=message):
        study_from_toml(study_text(tmp_path, starts))


def test_start_is_not_swept_by_hand_nor_an_axis_nor_a_chain(tmp_path):
    with pytest.raises(ConfigError, match=r"\[starts\] table"):
        study_from_toml(study_text(tmp_path).replace("shear_rate = [10, 20]", "shear_rate = [10, 20]\nstart = [0, 1]"))
    with pytest.raises(ConfigError, match="not an axis"):
        study_from_toml(study_text(tmp_path) + '[refine]\naxes = ["shear_rate", "start"]\n'
                        'tolerance = { shear_rate = 0.5, start = 1 }\n')
    with pytest.raises(ConfigError, match="a chain runs along a parameter"):
        study_from_toml(study_text(tmp_path) + '[chain]\nalong = "start"\n')


def test_the_analysis_names_each_start_and_groups_the_runs_of_each_point(tmp_path):
    from hpcves.reports.analyze import analyze

    study = study_from_toml(study_text(tmp_path))
    assert run_campaign(study, study.output).exit_status == 0
    report = analyze(study.output, tmp_path / "analysis", case_figures="none", write_to_file=False)
    assert [r["start"] for r in report.rows] == ["published", "two_domains"] * 2
    header = (tmp_path / "analysis" / "regimes.csv").read_text().splitlines()[0].split(",")
    assert header[header.index("viscosity_ratio") + 1] == "start"          # right after the parameters
    text = (tmp_path / "analysis" / "attractors.md").read_text()
    assert (tmp_path / "analysis" / "attractors.png").exists()
    assert "2 points run from published and two_domains" in text
    # at psi_bar = 0.3 the phase settles to one tank-treading state whatever its start
    assert {r["regime"] for r in report.rows} == {"TT"}
    assert "| TT / TT | the same | 2 |" in text
    assert dataclasses.replace(study.cases[1].case.physics, initial_phase="published", phase_domains=1,
                               delta=0.05) == study.cases[0].case.physics
