"""A refinement of attractors ([refine] attractors = true with [starts]): every point runs from every
start, its outcome is the set of regimes they reach, and the borders of coexistence are traced like
any boundary.

The logic on a synthetic map (refine_stages.outcomes), then a tiny real campaign.
"""
import csv
import math

import pytest

from hpcves.analysis import refine
from hpcves.campaign.driver import run_campaign
from hpcves.campaign.refine_stages import outcomes
from hpcves.campaign.study import study_from_toml
from hpcves.model.params import ConfigError

PLANE = """
[campaign]
name = "coexist"
output = "{output}"
t_end = 3.0
[physics]
psi_bar = 0.48
[numerics]
N = 32
dt = 1e-3
[run]
max_spectral_tail = 1.0          # N = 32 on purpose (fast)
until_decided = true
sample_interval = 0.005
snapshot_interval = 0.05
[sweep]
psi_bar = [0.3, 0.5]
shear_rate = [10.0, 40.0]
[starts]
published = {{}}
two_domains = {{ initial_phase = "domains", phase_domains = 2, delta = 0.16 }}
[refine]
axes = ["shear_rate", "psi_bar"]
tolerance = {{ shear_rate = 0.5, psi_bar = 0.1 }}
max_cases = 40
attractors = true
"""


def plane(output="x.h5", **replace):
    text = PLANE.format(output=output)
    for old, new in replace.items():
        text = text.replace(old, new)
    return text


def truth(S, psi_bar, start):
    """A synthetic bistable map: below psi_bar = 0.45 every start tank-treads; above it the published
    start phase-treads from S = 20 on, the two-domain start tank-treads."""
    if psi_bar < 0.45 or start == 1.0:
        return "TT"
    return "PT" if S >= 20 else "TT"


def trace(study, max_stages=30):
    """Run the refinement against ``truth``: (found, final outcome)."""
    found = []
    for _ in range(max_stages):
        (outcome,) = outcomes(study, found)
        if outcome.state.status != refine.RUNNING:
            return found, outcome
        for S, psi_bar in outcome.state.next_points:
            for start in study.point_starts:
                if not any(f[1:3] == (S, psi_bar) and f[5] == start for f in found):
                    found.append((0, S, psi_bar, truth(S, psi_bar, start), None, start))
    raise AssertionError("no end")


def test_a_point_is_the_set_of_regimes_its_starts_reach():
    assert refine.joint(["TT", "PT"]) == refine.joint(["PT", "TT", "PT"]) == "PT+TT"
    assert refine.joint(["TT", "TT"]) == "TT"
    assert refine.joint(["TT", "undecided"]) == "undecided"
    assert refine.decided("PT+TT") and refine.decided("TU") and not refine.decided("failed")


def test_the_border_of_coexistence_is_bracketed_to_the_tolerances():
    study = study_from_toml(plane())
    assert study.point_starts == (0.0, 1.0) and study.refinements == ({},)
    found, outcome = trace(study)
    assert outcome.state.status == refine.CONVERGED
    assert set(outcome.regimes.values()) == {"TT", "PT+TT"}
    # every point ran from both starts, once each
    points = {(S, p) for _, S, p, *_ in found}
    assert len(found) == 2 * len(points) == outcome.spent
    crossings = refine.boundary(outcome.settings, outcome.regimes, outcome.state.cells)
    assert crossings and {c.pair for c in crossings} == {"PT+TT|TT"}
    for c in crossings:            # each crossing lies on the true border, to the tolerance of its axis
        if c.x_low == c.x_high:    # across psi_bar: the border at 0.45
            assert c.y_low < 0.45 <= c.y_high and c.y_high - c.y_low <= 0.1 + 1e-12
        else:                      # across S: the border at 20
            assert c.x_low < 20 <= c.x_high and math.log(c.x_high / c.x_low) <= math.log1p(0.5) + 1e-12


def test_the_budget_counts_a_case_for_every_start():
    study = study_from_toml(plane(**{"max_cases = 40": "max_cases = 12"}))
    found, outcome = trace(study)
    assert outcome.state.status == refine.BUDGET and len(found) == outcome.spent <= 12


def test_attractors_need_starts_and_a_budget_for_them():
    with pytest.raises(ConfigError, match="name at least two"):
        study_from_toml(plane().split("[starts]")[0] + plane().split("[starts]")[1].split("\n", 3)[3])
    with pytest.raises(ConfigError, match="fewer than the 8 cases of the coarse grid from 2 starts"):
        study_from_toml(plane(**{"max_cases = 40": "max_cases = 6"}))
    # without the key, a refinement keeps the fingerprint it had before the key existed
    one = study_from_toml(plane(**{"attractors = true\n": ""}))
    assert one.fingerprint == study_from_toml(plane(**{"attractors = true\n": "attractors = false\n"})).fingerprint
    assert one.fingerprint != study_from_toml(plane()).fingerprint


@pytest.mark.slow          # ~40-55 s on a loaded machine; test_starts runs [starts] through a campaign in make test
def test_a_real_refinement_of_attractors_runs_and_is_analyzed(tmp_path):
    from hpcves.reports.analyze import analyze

    study = study_from_toml(plane(output=tmp_path / "coexist.h5", **{"t_end = 3.0": "t_end = 1.0"}))   # cheap
    summary = run_campaign(study, study.output)
    assert summary.exit_status == 0 and summary.searches[0].state.status == refine.CONVERGED
    report = analyze(study.output, tmp_path / "analysis", case_figures="none", write_to_file=False)
    rows = report.rows
    by_point = {}
    for r in rows:
        by_point.setdefault((r["shear_rate"], r["psi_bar"]), []).append(r)
    assert all(len(runs) == 2 and {r["start"] for r in runs} == {"published", "two_domains"}
               for runs in by_point.values())
    with open(tmp_path / "analysis" / "boundaries.csv") as f:
        pairs = {r["pair"] for r in csv.DictReader(f)}
    # the outcomes that meet at the traced borders are the sets of regimes the two starts reached
    found = {refine.joint(r["regime"] for r in runs) for runs in by_point.values()}
    assert all(set(p.split("|")) <= found for p in pairs)
    assert (tmp_path / "analysis" / "attractors.png").exists()


def test_the_plan_prices_every_start_of_the_coarse_grid():
    from hpcves.campaign.plan import plan

    study = study_from_toml(plane())
    planned = plan(study, lambda case: 1e-3)
    assert planned.first.cases == 2 * 2 * 2            # 2 x 2 coarse points, 2 starts each
