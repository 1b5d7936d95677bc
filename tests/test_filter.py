"""numerics.filter_order: the exponential filter of the tangent angle's explicit part.

With p > 0 the explicit part G = F + lam theta of theta_t = -lam theta + G is
multiplied mode by mode by rho(m) = exp(-10 (|m| / (N/2))^p): the modes well below
N/2 keep their dynamics, the modes near N/2 relax at their implicit rate. What it
costs in accuracy on sharp shapes is measured in docs/numerics.md ("A filter").
"""
import numpy as np
import pytest

from conftest import advance
from hpcves.model.params import Case, ConfigError, Numerics, Physics, RunControl
from hpcves.solver.timestepping import FILTER_STRENGTH, Solver


def solver(N=64, filter_order=0, **physics):
    physics = {"shear_rate": 10.0, "psi_bar": 0.3, "excess_length": 0.94, **physics}
    return Solver(Case(Physics(**physics), Numerics(N=N, dt=1e-3, filter_order=filter_order), RunControl(t_end=1.0)))


def test_the_filtered_rate_is_the_rate_in_the_resolved_modes_and_the_relaxation_near_N_over_2():
    plain, filtered = solver(), solver(filter_order=25)
    state = advance(plain, plain.initial_state(), 50)
    fft, lam = plain.sp.fft, plain.lam_theta
    F, F_f = fft.rfft(plain.rates(state).theta), fft.rfft(filtered.rates(state).theta)
    eta = np.abs(plain.sp.k) / abs(plain.sp.k[-1])
    G = F + lam * fft.rfft(state.theta)
    rho = np.exp(-FILTER_STRENGTH * eta ** 25)
    np.testing.assert_allclose(F_f + lam * fft.rfft(state.theta), rho * G, rtol=0, atol=1e-9 * np.abs(G).max())
    low = eta <= 0.5                                   # rho = 1 - 3e-7 at most: the rate itself
    assert np.abs(F_f[low] - F[low]).max() <= 1e-6 * np.abs(F).max()
    assert rho[-3] < 0.2 and rho[-1] < 1e-4            # mode N/2 - 2 of 64 nodes, the last one theta keeps


def test_filter_order_is_checked_and_left_out_of_fingerprints_when_off():
    for bad in (3, -1, 2.5, True, 100):
        with pytest.raises(ConfigError, match="filter_order"):
            Numerics(filter_order=bad)
    off, on = (Case(numerics=Numerics(filter_order=p)).significant()["numerics"] for p in (0, 25))
    assert "filter_order" not in off and on["filter_order"] == 25
