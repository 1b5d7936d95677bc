"""numerics.dealias: the right-hand sides computed on r N nodes and truncated to the N modes.

On N nodes the products that make up the rates (curvature squared times the bending
moment, e^{i theta}, the double well of psi) have modes up to ~N and beyond; sampled on
the N nodes, those above N/2 fold back onto the resolved modes. Computing the rates
on the interpolant's samples at r N nodes and keeping the lowest N modes removes that
(exactly for quadratic products at r = 3/2). Where nothing folds the rates are the
plain ones; where it does they are the Galerkin projection of the fine-grid rates.
"""
import h5py
import numpy as np
import pytest

from conftest import advance
from hpcves.config import case_from_toml
from hpcves.model.params import Case, ConfigError, Numerics, Physics, RunControl
from hpcves.numerics.spectral import resample
from hpcves.run.store import FINISHED, INTERRUPTED
from hpcves.solver.timestepping import Solver
from jobs import GROWING, history, resume_in_process, run_in_process, same_case_files


def solver(N, dealias=1.0, **physics):
    physics = {"shear_rate": 10.0, "psi_bar": 0.3, "excess_length": 0.94, **physics}
    return Solver(Case(Physics(**physics), Numerics(N=N, dt=1e-3, dealias=dealias), RunControl(t_end=1.0)))


def fields(rates):
    """The rates' arrays by name."""
    return {"theta": rates.theta, "psi": rates.psi, "velocity": rates.flow.velocity,
            "tension": rates.flow.tension_eff, "mu": rates.mu}


def on(state, solver_at):
    """``state`` of N nodes interpolated to the nodes of ``solver_at``."""
    M = solver_at.sp.N
    return type(state)(step=0, theta=resample(state.theta, M), psi=resample(state.psi, M), center=state.center)


def without_top_modes(values, sp):
    """``values`` with the modes N/2 - 1 and N/2 removed (theta_tilde's projection drops them)."""
    hat = sp.fft.rfft(values)
    hat[-2:] = 0
    return sp.fft.irfft(hat)


def test_where_nothing_folds_the_dealiased_rates_are_the_plain_ones():
    # a nearly round vesicle with its first phase (a cosine): resolved to round-off on 256 nodes
    kw = dict(psi_bar=0.3, excess_length=0.2)
    plain = solver(256, **kw)
    state = plain.initial_state()
    theta_tail = np.abs(plain.sp.fft.rfft(state.theta))[64:].max()
    psi_tail = np.abs(plain.sp.fft.rfft(state.psi))[64:].max()
    assert max(theta_tail, psi_tail) < 1e-13 * 256             # the state lives below N/4
    reference = plain.rates(state)
    for r in (1.5, 2.0):
        dealiased = solver(256, dealias=r, **kw)
        assert dealiased.padded_N == round(r * 256)
        rates = dealiased.rates(state)
        for name, values in fields(rates).items():
            expected = fields(reference)[name]
            # the tension solve stops at a residual of 1e-8 (flow.MembraneFlow), and psi's rate is mu's
            # second derivative: its round-off is mu's times k_max^2 ~ (N/2)^2 in units of the length
            bound = 1e-12 * (256 / 2) ** 2 if name == "psi" else 1e-9
            np.testing.assert_allclose(values, expected, rtol=0, atol=bound * np.abs(expected).max(), err_msg=name)
        assert abs(rates.center - reference.center) <= 1e-10 and abs(rates.shift - reference.shift) <= 1e-10


def test_where_products_fold_the_dealiased_rates_are_the_fine_grids_truncated_and_the_plain_ones_are_not():
    # the deflated ellipse (tip curvature ~26) on 64 nodes, a few steps on: content up to N/2
    N, kw = 64, dict(excess_length=2.3, psi_bar=0.48, shear_rate=5.0)
    plain = solver(N, **kw)
    state = advance(plain, plain.initial_state(), 20)
    fine = solver(8 * N, **kw)
    exact = {name: resample(values, N) for name, values in fields(fine.rates(on(state, fine))).items()}
    plain_err, dealiased_err = {}, {r: {} for r in (1.5, 2.0)}
    plain_rates = fields(plain.rates(state))
    rates = {r: fields(solver(N, dealias=r, **kw).rates(state)) for r in (1.5, 2.0)}
    for name, expected in exact.items():
        scale = np.abs(expected).max()
        if name == "theta":
            expected = without_top_modes(expected, plain.sp)
        clean = (lambda v: without_top_modes(v, plain.sp)) if name == "theta" else (lambda v: v)
        plain_err[name] = np.abs(clean(plain_rates[name]) - expected).max() / scale
        for r in rates:
            dealiased_err[r][name] = np.abs(clean(rates[r][name]) - expected).max() / scale
    # the plain rates carry the folded modes: percent-level errors on this grid
    assert plain_err["theta"] > 1e-3, plain_err
    for r in (1.5, 2.0):
        for name in exact:
            assert dealiased_err[r][name] < plain_err[name] / 10, (r, name, dealiased_err[r], plain_err)
    # twice the nodes leave far less than the 3/2 rule (e^{i theta}, the saturating law and the tension
    # solve are not quadratic): 1e-7 against 1e-4 and 7e-2 (plain) on theta
    for name in exact:
        assert dealiased_err[2.0][name] < dealiased_err[1.5][name] / 10, (name, dealiased_err)


def test_dealias_is_checked_and_left_out_of_fingerprints_when_off():
    for bad in (1.2, 3.0, True, "2", 0.5):
        with pytest.raises(ConfigError, match="dealias"):
            Numerics(dealias=bad)
    with pytest.raises(ConfigError, match="even integer"):
        Numerics(N=66, dealias=1.5)                         # 99 nodes
    with pytest.raises(ConfigError, match="dense"):
        Numerics(N=64, N_max=4096, dealias=1.5)
    assert Numerics(dealias=2).dealias == 2.0 and isinstance(Numerics(dealias=2).dealias, float)
    assert Numerics(N=64, N_max=256, dealias=2).grid() == "N = auto (64-256), rates on 2 N"
    assert Numerics(N=64).grid() == "N = 64"
    off, on_ = (Case(numerics=Numerics(dealias=r)).significant()["numerics"] for r in (1.0, 1.5))
    assert "dealias" not in off and on_["dealias"] == 1.5


DEALIASED = GROWING.format(t_end=0.05).replace("rtol = 1e-3", "rtol = 1e-3\ndealias = 1.5")


def test_a_dealiased_run_resumed_across_a_resize_is_bitwise_the_same(tmp_path):
    case = case_from_toml(DEALIASED)
    assert case.numerics.dealias == 1.5
    assert run_in_process(case, tmp_path / "a.h5").status == FINISHED
    assert run_in_process(case, tmp_path / "b.h5", max_steps=700).status == INTERRUPTED
    # stopped on 24 nodes, at step 700, and on 48 at step 1100 (the run grows at step 1036, t = 0.01)
    assert history(tmp_path / "a.h5") == [(0.0, 24), (0.01, 48)]
    assert resume_in_process(tmp_path / "b.h5", stops=(400, None)).status == FINISHED
    same_case_files(tmp_path / "a.h5", tmp_path / "b.h5", checkpoints=True)


AUTHORS_START = """
[physics]
psi_bar = 0.48
shear_rate = {S}
excess_length = {Delta}
initial_shape = "smoothed"
psi_init_coordinate = "ellipse_parameter"
[numerics]
N = "auto"
N_min = 64
N_max = 512
rtol = 1e-3
dealias = {dealias}
[run]
t_end = {t_end}
sample_interval = 0.02
snapshot_interval = 1.0
checkpoint_interval = 2.0
"""


@pytest.mark.slow
def test_the_authors_start_that_fails_on_512_plain_nodes_runs_dealiased_below_N_max(tmp_path):
    # without dealiasing this case climbs to N_max = 512 and stops as under-resolved at t = 12.03, its
    # spectrum rising toward N/2 (docs/numerics.md, "De-aliased rates"); de-aliased (~1.5 min on one core)
    # it stays on 192 and 384 nodes with its tails within resize_tail
    case = case_from_toml(AUTHORS_START.format(S=7.0710678, Delta=2.65, dealias=2, t_end=14.0))
    outcome = run_in_process(case, tmp_path / "a.h5")
    assert outcome.status == FINISHED, outcome.message
    assert max(N for _, N in history(tmp_path / "a.h5")) < case.numerics.N_max
    with h5py.File(tmp_path / "a.h5", "r") as f:
        n = f["timeseries/length"][()]
        tails = np.maximum(f["timeseries/tail_theta"][1:n], f["timeseries/tail_psi"][1:n])
    assert tails.max() <= case.numerics.resize_tail
