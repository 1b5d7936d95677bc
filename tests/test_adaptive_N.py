"""N adapting during a run (numerics.N = "auto"): the resize, the rule, the record, resume across a resize."""
import math

import h5py
import numpy as np
import pytest

from hpcves.analysis import grids
from hpcves.config import case_from_toml
from hpcves.model import geometry
from hpcves.model.params import Case, ConfigError, Numerics, Physics
from hpcves.numerics.spectral import fft_sizes, resample, spectral_tail, tail_on
from hpcves.run import resolution, schedule
from hpcves.run.store import FAILED, FINISHED, INTERRUPTED
from hpcves.solver.timestepping import Solver
from jobs import GROWING, history, resume_in_process, run_in_process, same_case_files


def band_limited(N, top, seed=0):
    """Samples on N nodes of a random real trigonometric polynomial of modes 0 ... top, and the polynomial."""
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=top + 1), rng.normal(size=top + 1)

    def f(alpha):
        m = np.arange(top + 1)[:, None]
        return (a[:, None] * np.cos(2 * np.pi * m * alpha) + b[:, None] * np.sin(2 * np.pi * m * alpha)).sum(0)

    return f(np.arange(N) / N), f


def test_resampling_is_exact_for_band_limited_fields_and_growing_then_shrinking_returns_the_field():
    samples, f = band_limited(32, 15)                     # modes below both Nyquist modes
    for N in (48, 64, 96, 256):
        assert np.max(np.abs(resample(samples, N) - f(np.arange(N) / N))) < 1e-12
        assert np.max(np.abs(resample(resample(samples, N), 32) - samples)) < 1e-12
    assert resample(samples, 32) is not samples and np.array_equal(resample(samples, 32), samples)
    other, g = band_limited(32, 15, seed=1)                # complex samples: each part resampled
    z = resample(samples + 1j * other, 64)
    assert np.iscomplexobj(z) and np.max(np.abs(z - (f(np.arange(64) / 64) + 1j * g(np.arange(64) / 64)))) < 1e-12


def test_the_sizes_are_fft_friendly_and_the_tail_on_a_smaller_grid_is_that_grids_tail():
    assert fft_sizes(16, 512) == (16, 24, 32, 48, 64, 96, 128, 192, 256, 384, 512)
    samples, _ = band_limited(64, 20)
    f_hat = np.fft.rfft(samples)
    for M in (48, 64):
        assert tail_on(f_hat, 64, M) == pytest.approx(spectral_tail(np.fft.rfft(resample(samples, M)), M), rel=1e-9)


def test_N_auto_in_a_file_and_its_errors():
    case = case_from_toml('[numerics]\nN = "auto"\nrtol = 1e-3')
    assert (case.numerics.N, case.numerics.N_max, case.numerics.adaptive_N) == (64, 512, True)
    case = case_from_toml('[numerics]\nN = "auto"\nN_min = 32\nN_max = 128\nrtol = 1e-3')
    assert (case.numerics.N, case.numerics.N_max) == (32, 128)
    assert not case_from_toml("[numerics]\nN = 64").numerics.adaptive_N
    for text, words in (('N = "fine"', 'must be an integer, or "auto"'),
                        ("N = 64\nN_min = 32", 'only with N = "auto"'),
                        ("N = 128\nN_max = 64", "must be above N = 128"),
                        ('N = "auto"\nN_max = 0', "give the largest N"),
                        ('N = "auto"\nresize_tail = 0.01', "must be below run.max_spectral_tail")):
        with pytest.raises(ConfigError, match=words):
            case_from_toml(f"[numerics]\n{text}\nrtol = 1e-3")
    # N fixed: the new options stay out of what a study's fingerprint covers (files of before keep theirs)
    assert "N_max" not in Case().significant()["numerics"]


def test_a_resized_state_keeps_length_area_and_the_psi_integral_and_its_history():
    case = Case(physics=Physics(excess_length=0.94, psi_bar=0.4, shear_rate=10.0), numerics=Numerics(N=64, rtol=1e-3))
    solver, clock = Solver(case), schedule.clock(case)
    state = solver.initial_state()
    for _ in range(30):                                   # a history: levels n-1, n-2 and the rates
        state, _ = clock.take_step(solver, state, solver.rates(state))
    for N in (96, 128):
        larger, grown = solver.resized(state, N)
        assert larger.sp.N == grown.N == N and larger.area0 == solver.area0
        area = geometry.enclosed_area(grown.theta + larger.sp.circle_angle, larger.sp)
        assert geometry.enclosed_area(state.theta + solver.sp.circle_angle, solver.sp) == pytest.approx(solver.area0,
                                                                                                   rel=1e-13)
        assert area == pytest.approx(solver.area0, rel=1e-13)     # the projection's target, on either grid
        assert grown.psi.mean() == pytest.approx(state.psi.mean(), abs=1e-15)      # int psi ds = L mean(psi)
        length = np.sum(np.abs(larger.sp.ds_complex(larger.shape(grown).z))) * larger.sp.length / N
        assert length == pytest.approx(case.physics.length, rel=1e-11)
        assert ((grown.t, grown.step, grown.dt_prev, grown.dt_next)
                == (state.t, state.step, state.dt_prev, state.dt_next))
        back, returned = larger.resized(grown, 64)       # and back: the same state to round-off
        for name in ("theta", "psi", "prev_theta", "prev_psi", "prev_rate_psi", "prev2_psi"):
            assert np.max(np.abs(getattr(returned, name) - getattr(state, name))) < 1e-7, name
        # the rate of theta_tilde, without the top two modes that 64 nodes drop from every step
        rate = solver.sp.project(state.prev_rate_theta, solver._resolved)
        assert np.max(np.abs(returned.prev_rate_theta - rate)) < 1e-9 * np.max(np.abs(rate))


def spectrum(N, kappa):
    """rfft of a field on N nodes whose modes decay as exp(-kappa m)."""
    m = np.arange(N // 2 + 1)
    return np.where(m > 0, np.exp(-kappa * m), 0.0).astype(complex)


def test_the_rule_grows_on_a_tail_shrinks_after_a_quiet_time_and_answers_the_same_when_asked_again():
    case = Case(physics=Physics(shear_rate=10.0),
                numerics=Numerics(N=32, N_max=256, rtol=1e-3, resize_tail=1e-3, shrink_after=2.0))
    assert resolution.sizes(case) == (32, 48, 64, 96, 128, 192, 256)
    odd = Case(numerics=Numerics(N=40, N_max=200, rtol=1e-3))      # bounds off the FFT sizes: both still taken
    assert resolution.sizes(odd) == (40, 48, 64, 96, 128, 192, 200) and resolution.larger_N(odd, 192) == 200
    with pytest.raises(ConfigError, match="N_max = 201: must be even"):
        Numerics(N=40, N_max=201)
    heavy = spectrum(32, 0.15)                            # tail ~ exp(-0.15 * 11) >> 1e-3
    N, since = resolution.decide(case, heavy, None, 32, math.nan, 0.0)
    assert N in resolution.sizes(case) and N > 32 and math.isnan(since)
    below = resolution.sizes(case)[resolution.sizes(case).index(N) - 1]
    assert spectral_tail(spectrum(N, 0.15), N) <= 1e-3 / resolution.GROW_MARGIN       # grown far enough,
    assert spectral_tail(spectrum(below, 0.15), below) > 1e-3 / resolution.GROW_MARGIN  # and no further
    assert resolution.decide(case, spectrum(256, 0.01), None, 256, math.nan, 0.0)[0] == 256     # N_max: stays
    smooth = spectrum(96, 1.0)                            # 64 nodes would hold it far within the bound
    N, since = resolution.decide(case, smooth, smooth, 96, math.nan, 1.0)
    assert (N, since) == (96, 1.0)                        # quiet from t = 1 ...
    assert resolution.decide(case, smooth, smooth, 96, since, 1.0) == (96, 1.0)      # (asked again: the same)
    assert resolution.decide(case, smooth, smooth, 96, since, 1.1) == (96, 1.0)      # ... 1 shear time: not yet
    N, since = resolution.decide(case, smooth, smooth, 96, 1.0, 1.25)                # 2.5 shear times: one size down
    assert N == 64 and math.isnan(since)
    noisy = spectrum(96, 0.3)            # resolved on 96 nodes (tail 7e-5), not quiet on 64 (1e-3): the clock stops
    N, since = resolution.decide(case, smooth, noisy, 96, 1.0, 1.1)
    assert N == 96 and math.isnan(since)
    N, since = resolution.decide(case, spectrum(32, 1.0), None, 32, 0.0, 100.0)
    assert N == 32 and math.isnan(since)                  # never below numerics.N


SHRINKING = """
[physics]
psi_bar = 0.48
shear_rate = 28.0
excess_length = 2.3
[numerics]
N = "auto"
N_min = 16
N_max = 96
resize_tail = 1e-2
shrink_after = 0.5
rtol = 1e-3
[run]
t_end = {t_end}
sample_interval = 0.005
snapshot_interval = 0.02
checkpoint_interval = 0.02
max_spectral_tail = 0.05
"""


# stops: steps of each call. Growing: 24 -> 48 nodes at t = 0.01, step ~1040; shrinking: 96 -> 64 at
# t = 0.045, step ~2420, the smaller grid quiet from t = 0.025 (step ~2380)
@pytest.mark.parametrize("text, stops", [(GROWING, (1000, 60, None)), (SHRINKING, (2390, 40, None))],
                         ids=["growing", "shrinking"])
def test_a_run_resized_on_its_way_is_bitwise_the_same_when_killed_and_resumed_across_the_resizes(tmp_path, text, stops):
    case = case_from_toml(text.format(t_end=0.1))
    assert run_in_process(case, tmp_path / "a.h5").status == FINISHED
    changes = history(tmp_path / "a.h5")
    assert len(changes) == 2, changes                      # it did resize, once
    assert run_in_process(case, tmp_path / "b.h5", max_steps=stops[0]).status == INTERRUPTED
    resumed_from = []
    assert resume_in_process(tmp_path / "b.h5", stops=stops[1:],
                             before=lambda store: resumed_from.append(store.read_checkpoint()[0])).status == FINISHED
    same_case_files(tmp_path / "a.h5", tmp_path / "b.h5", checkpoints=True)
    # the calls stopped on both grids, and the shrinking one while the smaller grid was being watched
    assert [s.N for s in resumed_from] == [changes[0][1], changes[1][1]]
    assert (text is GROWING) or changes[1][0] > resumed_from[0].quiet_since > 0
    with h5py.File(tmp_path / "a.h5", "r") as f:
        assert f["snapshots/x"].shape[1] == case.numerics.N_max            # snapshots on the N_max grid
        assert np.all(np.isfinite(f["snapshots/psi"][: f["snapshots/length"][()]]))


def test_a_growing_run_starts_on_the_grid_its_start_needs_and_grows_when_psi_sharpens(tmp_path):
    case = case_from_toml(GROWING.format(t_end=0.05))
    run_in_process(case, tmp_path / "a.h5")
    (t0, N0), (t1, N1) = history(tmp_path / "a.h5")[:2]
    # the ellipse's tail on 16 nodes is above resize_tail, on 24 within: it starts on 24
    tails = [max(Solver(case, N=n).initial_tails) for n in (16, 24)]
    assert tails[0] > 2e-2 >= tails[1] and (t0, N0) == (0.0, 24)
    assert t1 > 0 and N1 > N0
    # the samples count the steps: each grid's share of them (grids.grid_use) adds up to the run's
    with h5py.File(tmp_path / "a.h5", "r") as f:
        n = int(f["timeseries/length"][()])
        t, N, step = (f[f"timeseries/{k}"][:n] for k in ("t", "N", "step"))
        taken = [int(f[f"checkpoint/{slot}/meta"][1]) for slot in ("slot0", "slot1")]   # (valid, step, ...)
    assert step[0] == 0 and np.all(np.diff(step) > 0) and step[-1] == max(taken)
    use = grids.grid_use(t, N, step)
    assert set(use) == {N0, N1} | set(N[:-1].astype(int))
    assert sum(s for _, s in use.values()) == step[-1] and math.isclose(sum(u for u, _ in use.values()), t[-1])
    assert use[N0][1] == step[np.argmax(N > N0)]           # the steps before the first growth ran on N0
    from hpcves.reports.analyze import analyze
    analyze(tmp_path / "a.h5", tmp_path / "an", case_figures="none", write_to_file=False)
    assert f"Grids (N adapting): {grids.use_text(use)}." in (tmp_path / "an" / "regimes.md").read_text()


def test_grid_use_counts_each_interval_on_the_grid_its_first_sample_goes_on_with():
    t, N, step = [0.0, 1.0, 2.0, 4.0, np.nan], [64, 96, 96, 64, np.nan], [0, 10, 30, 40, np.nan]
    use = grids.grid_use(t, N, step)
    assert use == {64: (1.0, 10.0), 96: (3.0, 30.0)}
    assert grids.shares(use) == {64: (0.25, 0.25), 96: (0.75, 0.75)}
    assert grids.use_text(use) == "64: 25 % of the steps (25 % of the time), 96: 75 % of the steps (75 % of the time)"
    before = grids.grid_use(t, N)                             # a file written before the step series
    assert (grids.use_text(grids.combined([before, before]))
            == "64: 25 % of the simulated time, 96: 75 % of the simulated time")


DECIDING = """
[physics]
psi_bar = {psi_bar}
shear_rate = {S}
excess_length = {Delta}
[numerics]
N = {N}
rtol = 1e-3
[run]
t_end = {t_end}
sample_interval = 0.005
snapshot_interval = 0.5
until_decided = true
"""


@pytest.mark.parametrize("psi_bar, S, Delta, t_end, regime", [(0.3, 80.0, 0.19385328260599, 3.0, "PT"),
                                                               (0.5, 20.0, 2.3, 8.0, "TT")],
                         ids=["phase-separating", "deflated-tips"])
def test_where_a_fixed_coarse_grid_stops_as_under_resolved_N_auto_grows_and_decides(tmp_path, psi_bar, S, Delta,
                                                                                    t_end, regime):
    values = dict(psi_bar=psi_bar, S=S, Delta=Delta, t_end=t_end)
    fixed = run_in_process(case_from_toml(DECIDING.format(N=32, **values)), tmp_path / "fixed.h5")
    assert fixed.status != FINISHED and fixed.message.startswith("under-resolved"), fixed.message
    auto = case_from_toml(DECIDING.format(N='"auto"\nN_min = 32\nN_max = 128', **values))
    outcome = run_in_process(auto, tmp_path / "auto.h5")
    assert outcome.status == FINISHED and outcome.message.startswith(f"decided {regime}"), outcome.message
    changes = history(tmp_path / "auto.h5")
    assert max(N for _, N in changes) > 32                 # it needed more than the fixed grid had
    with h5py.File(tmp_path / "auto.h5", "r") as f:        # and held the tails within the watch's bound
        n = f["timeseries/length"][()]
        tails = np.maximum(f["timeseries/tail_theta"][1:n], f["timeseries/tail_psi"][1:n])
    assert tails.max() <= auto.run.max_spectral_tail


def test_campaigns_plan_N_auto_by_the_grid_its_start_needs_and_retry_with_N_max_doubled():
    from hpcves.campaign.study import study_from_toml

    deflated = Case(physics=Physics(excess_length=2.3, psi_bar=0.48, shear_rate=28.0),
                    numerics=Numerics(N=64, N_max=512, rtol=1e-3))
    assert resolution.expected_N(deflated) == 256         # tails on 192 nodes: 4.3e-4; on 256: 6.5e-5
    assert resolution.expected_N(Case(numerics=Numerics(N=64, rtol=1e-3))) == 64
    text = """
[campaign]
name = "auto"
output = "{out}"
[numerics]
N = "auto"
rtol = 1e-3
[sweep]
shear_rate = [5.0, 20.0]
psi_bar = [0.3, 0.5]
[refine]
max_N = 256
"""
    with pytest.raises(ConfigError, match='max_N = 256: with numerics.N = "auto" .* N_max = 512 .* at least 1024'):
        study_from_toml(text.format(out="x.h5"))
    retrying = study_from_toml(text.replace("max_N = 256", "max_N = 2048").format(out="x.h5"))
    numerics = [retrying.refine_case(0, 5.0, 0.3, "0001").case.numerics]
    while (changes := retrying.retry_numerics(numerics[-1], True, False)) is not None:
        numerics.append(retrying.refine_case(0, 5.0, 0.3, "0001", changes).case.numerics)
    assert [(n.N, n.N_max) for n in numerics] == [(64, 512), (64, 1024), (64, 2048)]
    study = study_from_toml(text.replace("[refine]\nmax_N = 256", "").format(out="x.h5"))     # a grid study
    assert study.base.numerics.adaptive_N and study.cases[0].cost == study.cases[0].case.estimated_steps * 64**2


@pytest.mark.parametrize("psi_bar, S, Delta, t_end, quantity", [(0.3, 80.0, 0.19385328260599, 1.0, "period"),
                                                                 (0.3, 80.0, 0.94, 2.0, "theta_mean")],
                         ids=["PT period", "TT inclination"])
def test_the_error_bars_with_the_grids_part_cover_a_coarse_run_against_a_fine_one(tmp_path, psi_bar, S, Delta,
                                                                                 t_end, quantity):
    from hpcves.analysis import accuracy
    from hpcves.reports.analyze import analyze

    rows = {}
    for N in (48, 96):                 # 48 nodes: tails 9e-4 and 2e-3 (docs/spatial_error.md); 96: 1e-6, 1e-5
        text = (f"[physics]\npsi_bar = {psi_bar}\nshear_rate = {S}\nexcess_length = {Delta}\n[numerics]\nN = {N}\n"
                f"rtol = 1e-3\n[run]\nt_end = {t_end}\nsample_interval = 0.005\n")
        run_in_process(case_from_toml(text), tmp_path / f"{N}.h5")
        [rows[N]] = analyze(tmp_path / f"{N}.h5", tmp_path / f"out{N}", case_figures=False).rows
    coarse, fine = rows[48], rows[96]
    assert coarse["regime"] == fine["regime"] == ("PT" if quantity == "period" else "TT")
    assert coarse[f"{quantity}_N_err"] > 10 * fine[f"{quantity}_N_err"] > 0      # the coarse grid's bar is larger
    difference = abs(coarse[quantity] - fine[quantity])
    assert difference <= accuracy.error_bar(coarse, quantity)[0] + accuracy.error_bar(fine, quantity)[0]


ONE_SIZE_UP = """
[physics]
psi_bar = 0.3
shear_rate = 10.0
[numerics]
N = {N}
resize_tail = 2e-2
rtol = 1e-3
[run]
t_end = 0.1
sample_interval = 0.01
snapshot_interval = 0.05
checkpoint_interval = 0.02
max_spectral_tail = 0.05
"""


def test_where_the_tension_solve_finds_the_shape_unresolved_N_auto_goes_one_size_up_and_resumes_bitwise(
        tmp_path, monkeypatch):
    from hpcves.model.flow import TensionSolveError

    rates = Solver.rates

    def unresolved_on_32_nodes_after(self, state):   # what flow.py raises when a shape outgrows its grid
        if self.sp.N == 32 and state.t >= 0.05:
            raise TensionSolveError("the tension leaves a stretching of 2e-6 of what it cancels: the shape is "
                                    "no longer resolved (reduce dt or increase N)")
        return rates(self, state)

    monkeypatch.setattr(Solver, "rates", unresolved_on_32_nodes_after)
    fixed = run_in_process(case_from_toml(ONE_SIZE_UP.format(N=32)), tmp_path / "fixed.h5")
    assert fixed.status != FINISHED and "TensionSolveError" in fixed.message
    auto = case_from_toml(ONE_SIZE_UP.format(N='"auto"\nN_min = 32\nN_max = 64'))
    assert run_in_process(auto, tmp_path / "a.h5").status == FINISHED
    (t0, N0), (t1, N1) = history(tmp_path / "a.h5")
    assert (t0, N0) == (0.0, 32) and 0.05 <= t1 <= 0.06 and N1 == 48
    stopped = run_in_process(auto, tmp_path / "b.h5", max_steps=1000)
    assert stopped.status == INTERRUPTED and stopped.t < 0.05                 # before the failure on 32 nodes
    assert resume_in_process(tmp_path / "b.h5").status == FINISHED
    same_case_files(tmp_path / "a.h5", tmp_path / "b.h5", checkpoints=True)


def test_where_the_tension_solve_finds_the_shape_unresolved_on_N_max_the_case_is_under_resolved(
        tmp_path, monkeypatch):
    from hpcves.model.flow import TensionSolveError
    from hpcves.run.verdict import FAILED_PREFIX, under_resolved

    rates = Solver.rates

    def unresolved_on_every_grid_after(self, state):
        if state.t >= 0.05:
            raise TensionSolveError("the tension leaves a stretching of 2e-6 of what it cancels: the shape is "
                                    "no longer resolved (reduce dt or increase N)")
        return rates(self, state)

    monkeypatch.setattr(Solver, "rates", unresolved_on_every_grid_after)
    auto = case_from_toml(ONE_SIZE_UP.format(N='"auto"\nN_min = 32\nN_max = 64'))
    result = run_in_process(auto, tmp_path / "a.h5")
    assert result.status == FAILED
    assert result.message.startswith("under-resolved: the tension solve finds the shape unresolved at t = 0.05")
    assert "on N = 64 (numerics.N_max: N grew as far as it may): the tension leaves a stretching" in result.message
    assert under_resolved({"regime": "failed", "reason": FAILED_PREFIX + result.message})


SEARCH_AUTO = """
[campaign]
name = "search_auto"
output = "{output}"
t_end = 1.5
[numerics]
N = "auto"
N_min = 16
N_max = 48
resize_tail = 1e-2
rtol = 1e-2
[run]
max_spectral_tail = 0.1
sample_interval = 0.01
snapshot_interval = 0.1
checkpoint_interval = 0.25
[search]
low = 30.0
high = 120.0
rel_tol = 0.5
[sweep]
psi_bar = [0.3]
"""


def test_a_search_campaign_with_N_auto_runs_under_mpi_as_it_runs_serially(tmp_path):
    """[search] with N adapting: every case keeps its own N history, and two ranks give the serial file."""
    from hpcves.analysis.search import CONVERGED
    from hpcves.campaign.driver import run_campaign
    from hpcves.campaign.file import CampaignFile
    from hpcves.campaign.study import study_from_toml
    from jobs import MPIRUN, assert_same_results, case_store, hpcves

    serial, parallel = tmp_path / "serial.h5", tmp_path / "mpi.h5"
    text = SEARCH_AUTO.format(output=serial)
    summary = run_campaign(study_from_toml(text), serial)
    search = summary.searches[0]
    assert summary.exit_status == 0 and search.state.status == CONVERGED
    assert 50 < search.state.low < search.state.high < 100         # TT at 70, PT at 80 (test_search_campaign)
    with h5py.File(serial, "r") as f:
        stores = [case_store(f, c) for c in CampaignFile(f).case_ids]
        Ns = [store.timeseries()["N"] for store in stores]
        assert all(store.width == 48 for store in stores)
    assert all(N[0] >= 16 for N in Ns) and len({int(n) for N in Ns for n in N}) > 1      # grids differ
    if MPIRUN is None:
        pytest.skip("no mpirun: the serial half ran")
    path = tmp_path / "mpi.toml"
    path.write_text(SEARCH_AUTO.format(output=parallel))
    result = hpcves("campaign", path, "--quiet", n=2)
    assert result.returncode == 0, result.stderr
    assert_same_results(parallel, serial)


STALLING = """
[physics]
psi_bar = 0.3
shear_rate = 80.0
[numerics]
N = 32
rtol = 1e-3
[run]
t_end = 0.2
sample_interval = 0.01
checkpoint_interval = 0.01
checkpoint_wall = 0
max_spectral_tail = 1.0
max_steps_per_shear_time = {limit}
"""


def test_the_stall_watch_counts_a_short_sample_interval_as_a_tenth_of_a_shear_time(tmp_path):
    """At S = 1 a sample interval of 0.01 is 0.01 shear times, but the start-up takes its steps whatever
    S is (1045 before t = 0.01 here): the watch allows limit x 0.1 steps there, not limit x 0.01."""
    slow = STALLING.replace("shear_rate = 80.0", "shear_rate = 1.0").replace("t_end = 0.2", "t_end = 0.05")
    assert run_in_process(case_from_toml(slow.format(limit=20000)), tmp_path / "a.h5").status == FINISHED
    stalled = run_in_process(case_from_toml(slow.format(limit=5000)), tmp_path / "b.h5")
    assert stalled.status == FAILED and stalled.message.startswith("stalled: the time step collapsed: 501 steps")


def test_the_stall_watch_floor_grows_as_the_tolerance_tightens(tmp_path):
    """Below rtol = 1e-3 the start-up takes about 1 / rtol more steps (5563 before t = 0.01 here at 1e-4,
    1019 at 1e-3): the floor grows with it (limit x 0.1 x 1e-3 / rtol), so a correct run is not stopped
    (the old floor, limit x 0.1 = 2000 steps, stopped it) -- and a step that collapses still is."""
    slow = (STALLING.replace("shear_rate = 80.0", "shear_rate = 1.0").replace("t_end = 0.2", "t_end = 0.02")
            .replace("rtol = 1e-3", "rtol = 1e-4"))
    assert run_in_process(case_from_toml(slow.format(limit=20000)), tmp_path / "a.h5").status == FINISHED
    stalled = run_in_process(case_from_toml(slow.format(limit=5000)), tmp_path / "b.h5")
    assert stalled.status == FAILED and stalled.message.startswith("stalled: the time step collapsed: 5001 steps")


@pytest.mark.slow
def test_the_spinodal_start_up_at_rtol_1e_4_is_not_taken_for_a_stall(tmp_path):
    """Delta = 0.94, psi_bar = 0.5625, S = 2 from the authors' start at rtol = 1e-4 (issue 65): 25059 steps
    before the first sample at t = 0.02, where the default watch allowed 2e4 before its floor grew with
    1 / rtol."""
    case = case_from_toml("""
[physics]
excess_length = 0.94
psi_bar = 0.5625
shear_rate = 2.0
initial_shape = "smoothed"
psi_init_coordinate = "ellipse_parameter"
[numerics]
N = "auto"
rtol = 1e-4
[run]
t_end = 0.04
sample_interval = 0.02
snapshot_interval = 0.02
checkpoint_interval = 0.02
""")
    outcome = run_in_process(case, tmp_path / "a.h5")
    assert outcome.status == FINISHED, outcome.message
    assert outcome.steps > 20000                    # more than the old floor allowed before t = 0.02


def test_a_run_whose_step_collapses_stops_as_stalled_the_same_when_resumed_on_its_way(tmp_path):
    """run.max_steps_per_shear_time: more steps in a sample interval than it allows stop the run as
    stalled (the start-up's ~240 steps in the first 4e-5 here are more than 300 per shear time allow for
    a sample interval of 0.8 shear times); counted from the last sample, also by a resumed run."""

    healthy = run_in_process(case_from_toml(STALLING.format(limit=2e5)), tmp_path / "healthy.h5")
    assert healthy.status == FINISHED
    stalling = case_from_toml(STALLING.format(limit=300))
    outcome = run_in_process(stalling, tmp_path / "a.h5")
    assert outcome.status == FAILED and outcome.message.startswith("stalled: the time step collapsed: 241 steps")
    assert "run.max_steps_per_shear_time = 300" in outcome.message
    run_in_process(stalling, tmp_path / "b.h5", max_steps=100)             # stopped inside the interval
    resumed = resume_in_process(tmp_path / "b.h5", stops=(50, None))
    assert resumed.status == FAILED and "(last good checkpoint kept)" in resumed.message    # the stops wrote one
    assert resumed.message.rsplit(" (", 1)[0] == outcome.message.rsplit(" (", 1)[0]
    same_case_files(tmp_path / "a.h5", tmp_path / "b.h5")
    with pytest.raises(ConfigError, match="max_steps_per_shear_time = -1"):
        case_from_toml(STALLING.format(limit=-1))
