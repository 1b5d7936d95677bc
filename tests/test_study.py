"""Campaign files: the grid of cases, end times, and the errors a user gets."""
import dataclasses
import itertools

import pytest

from hpcves.campaign.study import study_from_toml
from hpcves.model.params import ConfigError

BASE = """
[campaign]
name = "s"
output = "out/s.h5"
{campaign}
[numerics]
N = 32
[sweep]
{sweep}
"""


def study(sweep="", campaign=""):
    return study_from_toml(BASE.format(sweep=sweep, campaign=campaign))


def test_full_grid_in_order_with_ids_and_values():
    s = study('shear_rate = [40, 80]\npsi_bar = { linspace = [0.3, 0.7, 3] }\nB2 = 0.3')
    assert [c.case_id for c in s.cases] == [f"{i:04d}" for i in range(6)]
    assert [(c.swept["shear_rate"], c.swept["psi_bar"]) for c in s.cases] == [
        (40.0, 0.3), (40.0, 0.5), (40.0, 0.7), (80.0, 0.3), (80.0, 0.5), (80.0, 0.7)]
    assert all(c.case.physics.B2 == 0.3 and c.case.numerics.N == 32 for c in s.cases)
    assert s.cases[4].case.physics.psi_bar == 0.5 and s.cases[4].case.physics.shear_rate == 80.0


def test_logspace_takes_values_not_exponents():
    s = study("shear_rate = { logspace = [10, 1000, 3] }")
    assert [c.swept["shear_rate"] for c in s.cases] == [10.0, 100.0, 1000.0]


def test_end_time_in_shear_times_with_a_floor():
    s = study("shear_rate = [10, 100, 1000]", "shear_times = 50\nt_end_min = 1.0")
    assert [c.case.run.t_end for c in s.cases] == [5.0, 1.0, 1.0]
    absolute = study("shear_rate = [10, 100]", "t_end = 2.5")
    assert [c.case.run.t_end for c in absolute.cases] == [2.5, 2.5]


def test_sampling_in_samples_per_shear_time_never_coarser_than_the_base():
    s = study("shear_rate = [1, 10, 40, 1000]", "shear_times = 50\nsamples_per_shear_time = 20")
    base, dt = s.base.run.sample_interval, s.base.numerics.dt
    assert (base, dt) == (0.01, 1e-3)
    # 1 / (20 S) = 0.05 (coarser than the base: the base), 0.005, 0.00125, 5e-5 (finer than dt: dt)
    assert [c.case.run.sample_interval for c in s.cases] == [0.01, 0.005, 0.00125, 1e-3]
    plain = study("shear_rate = [10, 1000]", "shear_times = 50")
    assert [c.case.run.sample_interval for c in plain.cases] == [base, base]


def test_cost_orders_by_steps_and_resolution():
    s = study("shear_rate = [10, 100]", "shear_times = 50")
    assert s.cases[0].cost == pytest.approx(10 * s.cases[1].cost)


def test_fingerprint_ignores_comments_but_not_parameters():
    a = study("shear_rate = [40, 80]")
    b = study_from_toml("# a comment\n" + BASE.format(sweep="shear_rate = [40.0, 80.0]", campaign=""))
    c = study("shear_rate = [40, 81]")
    assert a.fingerprint == b.fingerprint != c.fingerprint


BAD = {
    "unknown campaign key": ('shear_rate = [1]', 'walltime = 3', ["unknown key", "walltime"]),
    "unsweepable key": ("epsilon = [0.1]", "", ["sweep over epsilon", "can be swept"]),
    "bad linspace": ("psi_bar = { linspace = [0.1, 0.5] }", "", ["sweep.psi_bar.linspace", "[start, stop, num]"]),
    "negative logspace": ("shear_rate = { logspace = [0, 10, 3] }", "", ["logspace", "> 0"]),
    "empty list": ("shear_rate = []", "", ["sweep.shear_rate", "empty"]),
    "string value": ('shear_rate = ["fast"]', "", ["sweep.shear_rate[0]", "number"]),
    "invalid case": ("psi_bar = [0.3, 1.5]", "", ["case 0001 (psi_bar = 1.5)", "physics.psi_bar = 1.5"]),
    "both end times": ("shear_rate = [1]", "t_end = 1.0\nshear_times = 3", ["t_end or shear_times"]),
    "zero shear without floor": ("shear_rate = [0, 10]", "shear_times = 3",
                                 ["case 0000 (shear_rate = 0)", "t_end_min"]),
}


@pytest.mark.parametrize("name", list(BAD))
def test_bad_campaign_files_name_the_problem(name):
    sweep, campaign, fragments = BAD[name]
    with pytest.raises(ConfigError) as info:
        study(sweep, campaign)
    for fragment in fragments:
        assert fragment in str(info.value), (fragment, str(info.value))


def test_base_case_errors_say_so():
    with pytest.raises(ConfigError, match="base case: numerics.N = 33"):
        study_from_toml("[numerics]\nN = 33\n")


def test_every_study_in_jobs_is_valid():
    from pathlib import Path

    from hpcves.campaign.study import load_study
    from hpcves.config import load_case

    jobs = Path(__file__).resolve().parent.parent / "jobs"
    studies = [p for p in jobs.glob("*.toml") if "[campaign]" in p.read_text()]
    assert {p.name for p in studies} >= {"demo.toml", "delta0194_S_psi.toml", "psi048_delta_S.toml",
                                         "delta094_S_psi.toml", "delta230_S_psi.toml"}
    from hpcves.campaign.search_stages import search_points

    for path in studies:
        study = load_study(path)
        if study.refine:           # a refinement's coarse grids, from every start of a refinement of attractors
            coarse = len(study.sweep[study.refine.axes[0]]) * len(study.sweep[study.refine.axes[1]])
            assert coarse * len(study.refinements) * len(study.point_starts) >= 4, path
            continue
        assert len(search_points(study) if study.search else study.cases) >= 4, path   # searches or cases
    for path in set(jobs.glob("*.toml")) - set(studies):
        load_case(path)


def test_the_reproduction_studies_are_valid_and_the_fine_set_is_as_tight_or_tighter():
    from pathlib import Path

    from hpcves.campaign.study import load_study

    jobs = Path(__file__).resolve().parent.parent / "jobs" / "reproduce"
    coarse = sorted(jobs.glob("*.toml"))
    deflated = ("psi048_cases", "psi048_delta_S", "delta094_S_psi", "delta230_S_psi")
    contrast = ("contrast_lambda_S_D0194", "contrast_lambda_S_D094", "contrast_lambda_psi")    # make contrast
    assert {p.stem for p in coarse} == {"homogeneous", "periods", "sc_b2", "sc_psi", *deflated,
                                       *(f"{name}_smoothed" for name in deflated), "delta230_chain", *contrast,
                                       "swinging", "publication_mode", "publication_mode_default",
                                       "publication_mode_fig7a", "publication_mode_fig7a_default"}
    # the publication's numerics and its twin in hpcves's: the same physics and points, only the numerics differ
    for folder, name in itertools.product((jobs, jobs / "fine"), ("publication_mode", "publication_mode_fig7a")):
        publication = load_study(folder / f"{name}.toml")
        default = load_study(folder / f"{name}_default.toml")
        assert publication.base.numerics.scheme == "ifab2" and default.base.numerics.adaptive
        assert publication.base.physics == default.base.physics and publication.sweep == default.sweep
    for name in contrast:              # refined over lambda and one more axis, lambda from 0.1 to 62.5
        study = load_study(jobs / f"{name}.toml")
        assert "viscosity_ratio" in study.refine.axes and study.sweep["viscosity_ratio"][0] == 0.1
        assert "viscosity_ratio" in study.refine_settings.log_keys()
    for name in deflated:              # each deflated study twice: from the ellipse and from the authors' start
        for folder in (jobs, jobs / "fine"):
            ellipse, smoothed = load_study(folder / f"{name}.toml"), load_study(folder / f"{name}_smoothed.toml")
            assert ellipse.base.physics.initial_shape == "ellipse"
            assert (smoothed.base.physics.initial_shape, smoothed.base.physics.psi_init_coordinate) == \
                ("smoothed", "ellipse_parameter")
            assert smoothed.sweep == ellipse.sweep
            if ellipse.refine:         # the same plane and retries; the coarse set may give the twin a smaller
                # budget or looser tolerances (make reproduce's 3 h), and a de-aliased twin no retry on
                # 2 N_max nodes (its rates would be on 4 N_max: hours a case), the fine set gives none
                assert smoothed.refine.axes == ellipse.refine.axes
                assert smoothed.refine.max_N == ellipse.refine.max_N or \
                    (folder == jobs and smoothed.refine.max_N == 0 and smoothed.base.numerics.dealias > 1)
                assert smoothed.refine.max_cases <= ellipse.refine.max_cases
                assert all(s >= e for (_, s), (_, e) in zip(smoothed.refine.tolerance, ellipse.refine.tolerance))
                assert folder == jobs or smoothed.refine == ellipse.refine
            # the same numerics but for de-aliased rates, which the authors' sharp start needs (its plain runs
            # failed on 512 nodes) and the ellipse's runs do not (none failed); docs/numerics.md, "De-aliased rates"
            assert dataclasses.replace(smoothed.base.numerics, dealias=1.0) == ellipse.base.numerics
            assert smoothed.base.numerics.dealias in (1.0, 2.0) and smoothed.times == ellipse.times
            assert smoothed.output != ellipse.output
    for path in coarse:
        study, fine = load_study(path), load_study(jobs / "fine" / path.name)
        assert fine.mode == study.mode and fine.output != study.output, path
        assert fine.base.numerics.N >= study.base.numerics.N, path
        if study.refine:
            assert fine.refine.axes == study.refine.axes and fine.refinements == study.refinements
            assert all(f <= c for (_, f), (_, c) in zip(fine.refine.tolerance, study.refine.tolerance)), path
            assert {k: fine.sweep[k] for k in fine.refine.axes} == {k: study.sweep[k] for k in study.refine.axes}
        if study.search:
            assert fine.search.rel_tol <= study.search.rel_tol and len(fine.searches) >= len(study.searches)
        if study.chain:               # the same chains from the same starts, over a range at least as wide
            assert fine.chain == study.chain and fine.starts == study.starts, path
            values, fine_values = study.sweep[study.chain.along], fine.sweep[study.chain.along]
            assert min(fine_values) <= min(values) and max(fine_values) >= max(values) and \
                len(fine_values) >= len(values), path
    # the continuation starts from the ellipse and from the authors' start
    chain = load_study(jobs / "delta230_chain.toml")
    assert [(name, values.get("initial_shape", "ellipse")) for name, values in chain.starts] == \
        [("ellipse", "ellipse"), ("authors", "smoothed")]
    # the plane of each refined diagram spans what the publication shows, low S included
    delta_s = load_study(jobs / "psi048_delta_S.toml")
    assert min(delta_s.sweep["shear_rate"]) == 1.0 and max(delta_s.sweep["shear_rate"]) == 350.0
    assert min(delta_s.sweep["excess_length"]) < 0.2 and max(delta_s.sweep["excess_length"]) == 3.0
    for name in ("delta094_S_psi", "delta230_S_psi"):
        study = load_study(jobs / f"{name}.toml")
        assert (min(study.sweep["psi_bar"]), max(study.sweep["psi_bar"])) == (0.25, 0.75)
        assert (min(study.sweep["shear_rate"]), max(study.sweep["shear_rate"])) == (1.0, 350.0)


SEARCH_TOML = """
[campaign]
name = "fp"
output = "out/fp.h5"
shear_times = 100
t_end_min = 1.0
[physics]
excess_length = 0.194
[numerics]
N = 32
[search]
low = 5.0
high = 80.0
[sweep]
psi_bar = [0.3, 0.5]
"""


def test_search_fingerprint_of_older_files_is_kept():
    """A search file records a fingerprint of what decides its cases, and --resume refuses
    any other. This one was written by the version before samples_per_shear_time existed:
    new options must leave it unchanged when they are not used (change it only with a
    migration of existing files). Files from before physics.bending_law ran the linear law: its
    study keeps the fingerprint once it says so, and today's default (saturating) is another study."""
    linear = SEARCH_TOML.replace("excess_length = 0.194", "excess_length = 0.194\nbending_law = \"linear\"")
    assert study_from_toml(linear).fingerprint == \
        "b69211a0947811a2d19a661353dd2203f7313add8746547afb026fb05b8bb73d"
    assert study_from_toml(SEARCH_TOML).fingerprint != study_from_toml(linear).fingerprint
    sampled = study_from_toml(linear.replace("t_end_min = 1.0", "t_end_min = 1.0\nsamples_per_shear_time = 10"))
    assert sampled.fingerprint != study_from_toml(linear).fingerprint
    smoothed = study_from_toml(linear.replace("excess_length = 0.194",
                                              "excess_length = 0.194\ninitial_shape = \"smoothed\""))
    assert smoothed.fingerprint != study_from_toml(linear).fingerprint      # the ellipse, as before, keeps it


def test_a_case_stored_before_the_bending_law_option_reads_back_as_the_linear_law(tmp_path):
    """Every stored case writes all its parameters; one written before physics.bending_law has
    none, and ran the linear law: it must resume with that, not with today's default."""
    from hpcves.config import case_from_toml, case_to_toml
    from hpcves.run.store import CaseStore, open_file

    case = case_from_toml("[physics]\nbending_law = \"linear\"\n[run]\nt_end = 0.1\n")
    with open_file(tmp_path / "old.h5", "w-") as f:
        store = CaseStore.create(f, case)
        text = case_to_toml(case)
        old = "\n".join(line for line in text.splitlines() if not line.startswith("bending_"))
        assert "bending_law" in text and "bending_law" not in old
        store.group.attrs["config"] = old
        assert store.case.physics.bending_law == "linear"
        assert store.case.to_dict() == case.to_dict()
        store.group.attrs["config"] = text.replace('"linear"', '"saturating"')
        assert store.case.physics.bending_law == "saturating"
    assert case_from_toml("[run]\nt_end = 0.1\n").physics.bending_law == "saturating"   # a new input


def test_the_start_round_trips_through_a_stored_case():
    from hpcves.config import case_from_toml, case_to_toml

    case = case_from_toml("[physics]\nexcess_length = 2.3\ninitial_shape = \"smoothed\"\n")
    assert 'initial_shape = "smoothed"' in case_to_toml(case)
    assert case_from_toml(case_to_toml(case), stored=True) == case
    assert case_from_toml("[physics]\n").physics.initial_shape == "ellipse"     # the default, and older files'


def test_numpy_numbers_in_a_case_are_written_as_plain_toml():
    """numpy's float64 is a float whose repr is "np.float64(...)": a case built from numpy numbers
    (an API user's sweep) must still store TOML that reads back as the same case."""
    import numpy as np

    from hpcves.config import case_from_toml, case_to_toml
    from hpcves.model.params import Case, Physics

    case = Case(Physics(excess_length=np.float64(0.7416264591), viscosity_ratio=np.float64(3.0)))
    text = case_to_toml(case)
    assert "np." not in text
    assert case_from_toml(text) == case
