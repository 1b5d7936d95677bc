"""A refinement runs an under-resolved point again at a larger N (``[refine] max_N``).

The logic on a synthetic map (refine_stages.outcomes: regimes and under-resolved
flags in, the next points and their attempts out), then tiny real cases: at
N = 16 with run.max_spectral_tail = 0.02 every psi_bar > 0 case stops as
under-resolved (its theta tail grows past the initial shape's 0.036) while the
homogeneous ones finish; at N = 32 all of them finish (tails <= 0.012).
"""
import csv

import h5py
import pytest

from hpcves.analysis import refine
from hpcves.campaign.driver import run_campaign
from hpcves.campaign.refine_stages import attempts, outcomes
from hpcves.campaign.study import study_from_toml
from hpcves.model.params import ConfigError
from hpcves.reports.analyze import analyze
from hpcves.reports.refinement import superseded
from hpcves.run.store import FAILED, FINISHED
from jobs import case_view

PLANE = """
[campaign]
name = "retry"
output = "x.h5"
[physics]
psi_bar = 0.48
[numerics]
N = 128
rtol = 1e-3
[sweep]
excess_length = [0.19385328260599, 0.9, 1.6, 2.3, 3.0]
shear_rate = [1.0, 5.0, 20.0, 80.0, 350.0]
[refine]
axes = ["shear_rate", "excess_length"]
tolerance = { shear_rate = 0.1, excess_length = 0.05 }
max_cases = 1000
"""


def truth(S, delta):
    """TT above Delta = 1.85, PT below; N = 256 needed in Delta 1.6-1.9 x S 4-10, 1024 at S 8-10."""
    regime = "TT" if delta > 1.85 else "PT"
    needed = 1024 if (1.6 <= delta <= 1.9 and 8 <= S <= 10) else 256 if (1.6 <= delta <= 1.9 and 4 <= S <= 10) \
        else 128
    return regime, needed


def trace(study, max_stages=60, truth=truth, found=()):
    """Run the refinement against ``truth``, each point's next run with the numerics its last asked
    for (Study.retry_numerics), from the runs ``found`` before: (found, final outcome)."""
    found, runs = list(found), [(x, y) for _, x, y, *_ in found]
    for _ in range(max_stages):
        (outcome,) = outcomes(study, found)
        if outcome.state.status != refine.RUNNING:
            return found, outcome
        for x, y in outcome.state.next_points:
            attempt, changes = outcome.retries.get((x, y, None), (0, None))
            assert attempt == sum(p == (x, y) for p in runs)       # a point is asked for again only to retry
            numerics = study.refine_case(0, x, y, "0000", changes).case.numerics
            regime, needed = truth(x, y)
            runs.append((x, y))
            if callable(needed):                  # creep: the regime needs resize_tail <= needed(...)
                crept = not needed(numerics.resize_tail)
                found.append((0, x, y, "undecided" if crept else regime,
                              study.retry_numerics(numerics, False, crept), None))
            elif numerics.N >= needed:
                found.append((0, x, y, regime, study.retry_numerics(numerics, False, False), None))
            else:
                found.append((0, x, y, "failed", study.retry_numerics(numerics, True, False), None))
    raise AssertionError("no end")


def test_an_under_resolved_point_runs_again_at_twice_its_n_until_max_n():
    without, outcome_0 = trace(study_from_toml(PLANE))
    with_retries, outcome = trace(study_from_toml(PLANE + "max_N = 256\n"))
    failed_0 = {p for p, r in outcome_0.regimes.items() if r == "failed"}
    failed = {p for p, r in outcome.regimes.items() if r == "failed"}
    assert failed_0 and outcome_0.spent == len(outcome_0.regimes)       # no retries without max_N
    # with max_N = 256 only the points that need 1024 stay failed, each run twice (N = 128, 256)
    assert failed and all(truth(*p)[1] == 1024 for p in failed)
    runs = {}
    for _, x, y, _, _, _ in with_retries:
        runs[(x, y)] = runs.get((x, y), 0) + 1
    assert max(runs.values()) == 2 and all(runs[p] == 2 for p in failed)
    assert outcome.spent == len(with_retries) == sum(runs.values()) > len(outcome.regimes)
    assert all(runs[p] == 2 for p, r in outcome.regimes.items() if truth(*p)[1] == 256)
    # every point that N = 256 resolves has its true regime; the boundary is sharp away from the failures
    assert all(r == truth(*p)[0] for p, r in outcome.regimes.items() if p not in failed)
    crossings = refine.boundary(outcome.settings, outcome.regimes, outcome.state.cells)
    blurry = [c for c in crossings if c.blurry]
    crossings_0 = refine.boundary(outcome_0.settings, outcome_0.regimes, outcome_0.state.cells)
    assert len(blurry) < sum(c.blurry for c in crossings_0)
    assert all(4 <= c.x_low and c.x_high <= 12 for c in blurry)              # around the N = 1024 patch
    assert outcome.state.status == outcome_0.state.status == refine.CONVERGED
    print(f"cases without retries {outcome_0.spent} ({len(failed_0)} failed, "
          f"{sum(c.blurry for c in crossings_0)} blurry); with max_N = 256 {outcome.spent} "
          f"({len(failed)} failed, {len(blurry)} blurry)")


def test_the_budget_counts_every_run_of_a_point():
    study = study_from_toml(PLANE.replace("max_cases = 1000", "max_cases = 60") + "max_N = 256\n")
    found, outcome = trace(study)
    assert outcome.state.status == refine.BUDGET and outcome.spent == len(found) <= 60


def test_attempts_count_the_earlier_cases_of_a_point():
    assert attempts([(0, 1, 2), (0, 3, 4), (0, 1, 2), (1, 1, 2), (0, 1, 2)]) == [0, 0, 1, 0, 2]


@pytest.mark.parametrize("extra, message", [
    ("max_N = 200\n", "max_N = 200: .* at least 256"),
    ("max_N = -1\n", "max_N = -1: must be >= 0"),
    ("max_N = 2.5\n", "max_N"),
])
def test_bad_max_n_is_refused(extra, message):
    with pytest.raises(ConfigError, match=message):
        study_from_toml(PLANE + extra)


def test_max_n_is_in_the_fingerprint_and_0_is_that_of_files_from_before_it():
    default, zero, retry = (study_from_toml(PLANE + extra).fingerprint for extra in ("", "max_N = 0\n",
                                                                                        "max_N = 256\n"))
    assert default == zero != retry
    study = study_from_toml(PLANE + "max_N = 512\n")
    numerics = study.refine_case(0, 5.0, 1.6, "0001").case.numerics
    Ns = [numerics.N]
    while (changes := study.retry_numerics(numerics, True, False)) is not None:
        numerics = study.refine_case(0, 5.0, 1.6, "0001", changes).case.numerics
        Ns.append(numerics.N)
    assert Ns == [128, 256, 512]
    assert study.retry_numerics(numerics, False, True) is None      # with a fixed N a creeping point stays


AUTO_PLANE = PLANE.replace("N = 128\n", 'N = "auto"\nN_min = 64\nN_max = 256\n')


def creeping(S, delta):
    """TT everywhere; in Delta 2-2.5 x S 1-3 the pattern creeps unless resize_tail <= 1e-6, and in
    Delta 2-2.5 x S 1-1.5 unless resize_tail <= 1e-8 (a synthetic map)."""
    if 2.0 <= delta <= 2.5 and 1 <= S <= 3:
        limit = 1e-8 if S <= 1.5 else 1e-6
        return "TT", lambda resize_tail: resize_tail <= limit * (1 + 1e-9)
    return "TT", 1


def test_a_creeping_point_runs_again_with_resize_tail_over_100_down_to_min_resize_tail():
    without, outcome_0 = trace(study_from_toml(AUTO_PLANE), truth=creeping)
    study = study_from_toml(AUTO_PLANE + "min_resize_tail = 1e-6\n")
    found, outcome = trace(study, truth=creeping)
    stuck_0 = {p for p, r in outcome_0.regimes.items() if r == "undecided"}
    stuck = {p for p, r in outcome.regimes.items() if r == "undecided"}
    assert stuck_0 and outcome_0.spent == len(outcome_0.regimes)        # no retries without the key
    # with min_resize_tail = 1e-6 one retry (1e-4 -> 1e-6) decides the points that need 1e-6; those that
    # need 1e-8 stay undecided after it
    assert stuck and len(stuck) < len(stuck_0) and all(p[0] <= 1.5 for p in stuck)
    runs, first = {}, {}
    for _, x, y, regime, _, _ in found:
        runs[(x, y)] = runs.get((x, y), 0) + 1
        first.setdefault((x, y), regime)
    crept_once = {p for p, r in first.items() if r == "undecided"}
    assert stuck < crept_once and all(runs[p] == 2 for p in crept_once) and max(runs.values()) == 2
    assert all(r == "TT" for p, r in outcome.regimes.items() if p not in stuck)
    assert outcome.spent == len(found) > len(outcome.regimes)
    # the retry changes resize_tail only, by 100
    numerics = study.refine_case(0, 1.0, 2.3, "0000").case.numerics
    changes = study.retry_numerics(numerics, False, True)
    assert changes == {"N_max": 256, "resize_tail": pytest.approx(1e-6, rel=1e-12), "rtol": 1e-3}
    again = study.refine_case(0, 1.0, 2.3, "0001", changes).case.numerics
    assert (again.N, again.N_max, again.dealias) == (numerics.N, numerics.N_max, numerics.dealias)
    assert study.retry_numerics(again, False, True) is None                 # 1e-8 < min_resize_tail
    # an under-resolved run again keeps the tighter tail, and doubles N_max (with max_N)
    retry = study_from_toml(AUTO_PLANE + "min_resize_tail = 1e-6\nmax_N = 512\n")
    assert retry.retry_numerics(again, True, False) == {"N_max": 512, "resize_tail": again.resize_tail, "rtol": 1e-3}


def test_a_finished_refinement_continued_with_min_resize_tail_runs_every_creeping_point_again():
    """Continued with the key, the points that crept run again even where, their neighbours decided, no
    cell needs them any more: the map keeps no point at a run a retry can decide."""
    found_0, outcome_0 = trace(study_from_toml(AUTO_PLANE), truth=creeping)
    study = study_from_toml(AUTO_PLANE + "min_resize_tail = 1e-6\n")
    base = study.base.numerics
    found = [(r, x, y, regime, study.retry_numerics(base, False, regime == "undecided"), start)
             for r, x, y, regime, _, start in found_0]
    crept = {(x, y) for _, x, y, regime, _, _ in found_0 if regime == "undecided"}
    (first,) = outcomes(study, found)
    assert first.state.status == refine.RUNNING and crept <= set(first.state.next_points)
    _, outcome = trace(study, truth=creeping, found=found)
    assert outcome.state.status == refine.CONVERGED
    assert {p for p, r in outcome.regimes.items() if r == "undecided"} == {p for p in crept if p[0] <= 1.5}
    assert all(r == "TT" for p, r in outcome.regimes.items() if p in crept and p[0] > 1.5)


@pytest.mark.parametrize("plane, extra, message", [
    (PLANE, "min_resize_tail = 1e-6\n", 'only a run with numerics.N = "auto"'),
    (AUTO_PLANE, "min_resize_tail = 1e-5\n", "min_resize_tail = 1e-05: .* give at most 1e-06"),
    (AUTO_PLANE, "min_resize_tail = -1e-6\n", r"must lie in \[0, 1\)"),
    (AUTO_PLANE, "min_resize_tail = 'small'\n", "min_resize_tail"),
])
def test_bad_min_resize_tail_is_refused(plane, extra, message):
    with pytest.raises(ConfigError, match=message):
        study_from_toml(plane + extra)


def unsettling(S, delta):
    """TT everywhere but in Delta 2-2.5 x S 30-90, PT there; its PT stays unsettled unless rtol <= 1e-4 (a
    synthetic map of the Delta = 2.3, psi_bar = 0.48, S = 40-80 phase-treading that rtol = 1e-3 misses)."""
    if 2.0 <= delta <= 2.5 and 30 <= S <= 90:
        return "PT", lambda rtol: rtol <= 1e-4 * (1 + 1e-9)
    return "TT", None


def trace_rtol(study, truth, max_stages=60):
    """As :func:`trace`, for a map whose points stay unsettled above an rtol."""
    found = []
    for _ in range(max_stages):
        (outcome,) = outcomes(study, found)
        if outcome.state.status != refine.RUNNING:
            return found, outcome
        for x, y in outcome.state.next_points:
            _, changes = outcome.retries.get((x, y, None), (0, None))
            numerics = study.refine_case(0, x, y, "0000", changes).case.numerics
            regime, settles = truth(x, y)
            unsettled = settles is not None and not settles(numerics.rtol)
            found.append((0, x, y, "undecided" if unsettled else regime,
                          study.retry_numerics(numerics, False, False, unsettled), None))
    raise AssertionError("no end")


def test_an_unsettled_point_runs_again_with_rtol_over_10_down_to_min_rtol():
    """The deflated studies' case (issue 65): rtol = 1e-3 leaves a phase-treading point unsettled, rtol =
    1e-4 decides it; with min_rtol = 1e-4 the refinement runs such points once more and traces the PT patch."""
    _, outcome_0 = trace_rtol(study_from_toml(PLANE), unsettling)
    study = study_from_toml(PLANE + "min_rtol = 1e-4\n")
    found, outcome = trace_rtol(study, unsettling)
    stuck_0 = {p for p, r in outcome_0.regimes.items() if r == "undecided"}
    assert stuck_0 and outcome_0.spent == len(outcome_0.regimes)                 # no retries without the key
    assert "PT" not in outcome_0.regimes.values()
    assert all(r == unsettling(*p)[0] for p, r in outcome.regimes.items())      # the true map, PT patch included
    assert "PT" in outcome.regimes.values() and all(unsettling(*p)[0] == "PT" for p in stuck_0)
    assert outcome.spent == len(found) > len(outcome.regimes)
    numerics = study.refine_case(0, 40.0, 2.3, "0000").case.numerics
    changes = study.retry_numerics(numerics, False, False, True)
    assert changes == {"N": 128, "resize_tail": numerics.resize_tail, "rtol": pytest.approx(1e-4, rel=1e-12)}
    again = study.refine_case(0, 40.0, 2.3, "0001", changes).case.numerics
    assert again.rtol == pytest.approx(1e-4) and study.retry_numerics(again, False, False, True) is None
    # an under-resolved run again keeps the tighter rtol
    retry = study_from_toml(PLANE + "min_rtol = 1e-4\nmax_N = 256\n")
    assert retry.retry_numerics(again, True, False)["rtol"] == again.rtol


@pytest.mark.parametrize("extra, message", [
    ("min_rtol = 1e-3\n", "min_rtol = 0.001: .* give at most 0.0001"),
    ("min_rtol = 1.5\n", r"must lie in \[0, 1\)"),
])
def test_bad_min_rtol_is_refused(extra, message):
    with pytest.raises(ConfigError, match=message):
        study_from_toml(PLANE + extra)
    with pytest.raises(ConfigError, match="only an adaptive step"):
        study_from_toml(PLANE.replace("rtol = 1e-3\n", "dt = 1e-3\n") + "min_rtol = 1e-5\n")


def test_min_resize_tail_is_not_in_the_fingerprint():
    """Lowered on a finished study, its creeping points run again; the cases run so far stay valid."""
    assert (study_from_toml(AUTO_PLANE).fingerprint
            == study_from_toml(AUTO_PLANE + "min_resize_tail = 1e-6\n").fingerprint
            == study_from_toml(AUTO_PLANE + "min_rtol = 1e-4\n").fingerprint)


TINY = """
[campaign]
name = "retry"
output = "{output}"
t_end = 1.5
[numerics]
N = 16
dt = 1e-3
[run]
max_spectral_tail = 0.02
sample_interval = 0.005
snapshot_interval = 0.05
checkpoint_interval = 0.5
checkpoint_wall = 0
[sweep]
shear_rate = [30.0, 120.0]
psi_bar = [0.0, 0.3]
[refine]
tolerance = {{ shear_rate = 0.5, psi_bar = 0.15 }}
max_cases = {max_cases}
max_N = 32
"""


@pytest.fixture(scope="module")
def retried(tmp_path_factory):
    """The tiny refinement with retries, run serially in this process: (study, file, summary)."""
    output = tmp_path_factory.mktemp("retry") / "retry.h5"
    study = study_from_toml(TINY.format(output=output, max_cases=30))
    summary = run_campaign(study, output)
    assert summary.exit_status == 0
    return study, output, summary


def test_a_campaign_runs_under_resolved_cases_again_at_twice_n(retried, tmp_path):
    study, output, summary = retried
    (outcome,) = summary.searches
    with h5py.File(output, "r") as f:
        n = int(f.attrs["n_cases"])
        cases = [case_view(f, f"{i:04d}") for i in range(n)]
        rows = [(float(g.attrs["physics.shear_rate"]), float(g.attrs["physics.psi_bar"]), int(g.attrs["numerics.N"]),
                 g["message"][()].decode() if isinstance(g["message"][()], bytes) else str(g["message"][()]))
                for g in cases]
    by_point = {}
    for S, psi, N, message in rows:
        by_point.setdefault((S, psi), []).append((N, message))
    for (S, psi), runs in by_point.items():
        if psi == 0.0:               # the homogeneous vesicle is resolved at N = 16
            assert [N for N, _ in runs] == [16], (S, psi, runs)
        else:                        # the others stop as under-resolved at 16, then finish at 32
            assert [N for N, _ in runs] == [16, 32], (S, psi, runs)
            assert runs[0][1].startswith("under-resolved: ") and "N = 16 does not resolve" in runs[0][1]
    assert "failed" not in outcome.regimes.values()
    assert outcome.spent == n > len(outcome.regimes)
    report = analyze(output, tmp_path / "analysis", write_to_file=False, case_figures=False)
    again = n - len(by_point)             # the runs after a point's first
    assert again > 0
    repeated = superseded(report.source)   # the runs a later one repeats: the first, under-resolved one
    assert len(repeated) == again
    assert all(rows[int(case)][3].startswith("under-resolved: ") for case in repeated)
    assert [(r["status"], int(r["cases"]), r["run_again"]) for r in report.refinements] == \
        [(outcome.state.status, n, again)]
    text = (tmp_path / "analysis" / "refinement.md").read_text()
    assert "runs again at 2 N (where N adapts: N_max doubled) while that is at most N = 32" in text
    assert "| run again |" in text
    with open(tmp_path / "analysis" / "regimes.csv") as f:
        table = list(csv.DictReader(f))
    assert [int(float(r["N"])) for r in table] == [N for _, _, N, _ in rows]


def test_a_refinement_with_retries_continues_when_its_budget_is_raised(retried, tmp_path):
    """Resumed from the file, the retries are rebuilt from the order of the cases (N doubles with each
    run of a point): the continued refinement makes the cases of the uninterrupted one."""
    _, reference, summary = retried
    output = tmp_path / "retry.h5"
    first = run_campaign(study_from_toml(TINY.format(output=output, max_cases=7)), output)
    assert [o.state.status for o in first.searches] == ["budget spent"]
    again = run_campaign(study_from_toml(TINY.format(output=output, max_cases=30)), output, resume=True)
    assert [(o.state.status, o.regimes, o.spent) for o in again.searches] == \
        [(o.state.status, o.regimes, o.spent) for o in summary.searches]
    with h5py.File(output, "r") as f, h5py.File(reference, "r") as g:
        assert f.attrs["n_cases"] == g.attrs["n_cases"]
        for i in range(int(g.attrs["n_cases"])):
            a, b = case_view(f, f"{i:04d}"), case_view(g, f"{i:04d}")
            assert [a.attrs[k] for k in ("numerics.N", "physics.shear_rate", "physics.psi_bar")] == \
                [b.attrs[k] for k in ("numerics.N", "physics.shear_rate", "physics.psi_bar")]
            assert a["status"][()] == b["status"][()]


def test_where_N_adapts_a_point_left_under_resolved_runs_again_with_N_max_doubled(tmp_path):
    """numerics.N = "auto": a run that N_max = 24 leaves under-resolved (the two-phase points) runs again
    with N_max = 48 (N_min unchanged) and finishes; the homogeneous points are resolved on 24 nodes."""
    auto = (TINY.replace("N = 16\ndt = 1e-3", 'N = "auto"\nN_min = 16\nN_max = 24\nresize_tail = 0.01\nrtol = 1e-2')
            .replace("max_N = 32", "max_N = 48"))
    output = tmp_path / "auto.h5"
    summary = run_campaign(study_from_toml(auto.format(output=output, max_cases=30)), output)
    assert summary.exit_status == 0
    by_point = {}
    with h5py.File(output, "r") as f:
        for i in range(int(f.attrs["n_cases"])):
            g = case_view(f, f"{i:04d}")
            message = g["message"][()]
            by_point.setdefault((float(g.attrs["physics.shear_rate"]), float(g.attrs["physics.psi_bar"])), []).append(
                (int(g.attrs["numerics.N"]), int(g.attrs["numerics.N_max"]), int(g["status"][()]),
                 message.decode() if isinstance(message, bytes) else str(message)))
    assert len(by_point) >= 4
    for (S, psi), runs in by_point.items():
        if psi == 0.0:
            assert [(N, N_max, status) for N, N_max, status, _ in runs] == [(16, 24, FINISHED)], (S, runs)
        else:
            assert [(N, N_max, status) for N, N_max, status, _ in runs] == [(16, 24, FAILED), (16, 48, FINISHED)]
            assert runs[0][3].startswith("under-resolved: ") and "N = 24 (numerics.N_max: N grew as far" in runs[0][3]
    (outcome,) = summary.searches
    assert "failed" not in outcome.regimes.values()


CREEPING_TINY = (TINY.replace("N = 16\ndt = 1e-3",
                              'N = "auto"\nN_min = 16\nN_max = 48\nresize_tail = 0.01\nrtol = 1e-2')
                 .replace("max_N = 32", "min_resize_tail = 1e-4"))


def resolutions(path):
    """(S, psi_bar, N_max, resize_tail, status) of every case of a file, in case order."""
    with h5py.File(path, "r") as f:
        return [(float(g.attrs["physics.shear_rate"]), float(g.attrs["physics.psi_bar"]),
                 int(g.attrs["numerics.N_max"]),
                 float(g.attrs["numerics.resize_tail"]), int(g["status"][()]))
                for g in (case_view(f, f"{i:04d}") for i in range(int(f.attrs["n_cases"])))]


def test_a_campaign_runs_creeping_cases_again_with_a_tighter_resize_tail_and_resumes_them(tmp_path, monkeypatch):
    """The mechanics on real runs: every two-phase case is taken as creeping (the tiny cases do not creep;
    the verdict itself is tested in test_periodicity.py), so it runs again with resize_tail 0.01 / 100 =
    min_resize_tail, and no more; stopped by its budget and continued, the refinement rebuilds those runs
    from the file and ends with the cases of the uninterrupted one."""
    import hpcves.run.verdict as verdict
    monkeypatch.setattr(verdict, "crept", lambda row: row["psi_bar"] > 0 and row["regime"] != "failed")
    reference = tmp_path / "whole.h5"
    summary = run_campaign(study_from_toml(CREEPING_TINY.format(output=reference, max_cases=30)), reference)
    assert summary.exit_status == 0
    cases = resolutions(reference)
    by_point = {}
    for S, psi, N_max, tail, status in cases:
        by_point.setdefault((S, psi), []).append((N_max, tail, status))
    assert len(by_point) >= 4
    for (S, psi), runs in by_point.items():
        expected = [(48, 0.01, FINISHED)] + ([(48, pytest.approx(1e-4, rel=1e-12), FINISHED)] if psi > 0 else [])
        assert runs == expected, (S, psi, runs)
    assert summary.run_again == len(cases) - len(by_point) > 0
    output = tmp_path / "continued.h5"
    first = run_campaign(study_from_toml(CREEPING_TINY.format(output=output, max_cases=5)), output)
    assert [o.state.status for o in first.searches] == ["budget spent"]
    again = run_campaign(study_from_toml(CREEPING_TINY.format(output=output, max_cases=30)), output, resume=True)
    assert resolutions(output) == cases
    assert [(o.state.status, o.regimes, o.spent) for o in again.searches] == \
        [(o.state.status, o.regimes, o.spent) for o in summary.searches]
    report = analyze(output, tmp_path / "analysis", write_to_file=False, case_figures=False)
    assert [int(r["run_again"]) for r in report.refinements] == [summary.run_again]
    assert "runs again with numerics.resize_tail / 100 while that is at least 0.0001" in \
        (tmp_path / "analysis" / "refinement.md").read_text()
