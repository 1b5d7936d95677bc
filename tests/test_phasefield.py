import numpy as np
import pytest

from conftest import make_solver
from hpcves.model import phasefield
from hpcves.numerics.spectral import Spectral


def test_double_well_derivatives():
    psi, h = np.linspace(-0.2, 1.2, 15), 1e-6
    g, g1, g2 = phasefield.double_well, phasefield.double_well_prime, phasefield.double_well_second
    assert np.allclose((g(psi + h) - g(psi - h)) / (2 * h), g1(psi), atol=1e-9)
    assert np.allclose((g1(psi + h) - g1(psi - h)) / (2 * h), g2(psi), atol=1e-9)


def test_initial_phase_and_its_two_readings():
    arclength = make_solver(psi_bar=0.3).initial_state().psi
    assert arclength.mean() == pytest.approx(0.3, abs=1e-15)         # mean is psi_bar exactly
    assert arclength.max() == pytest.approx(0.3 + 4 * 0.05)
    ellipse = make_solver(psi_bar=0.3, psi_init_coordinate="ellipse_parameter").initial_state().psi
    assert 1e-4 < np.abs(ellipse - arclength).max() < 0.1             # the two readings differ slightly


def test_homogeneous_vesicle_has_no_phase_dynamics():
    solver = make_solver(psi_bar=0.0, shear_rate=10.0)
    state = solver.initial_state()
    for _ in range(3):
        state, _, _ = solver.step(state)
    assert np.all(state.psi == 0.0)


def test_longest_spinodal_run():
    L = 2.0
    psi = np.zeros(40)
    assert phasefield.longest_spinodal_run(psi, L) == 0.0
    psi[[38, 39, 0, 1, 2]] = 0.5                                       # wraps around
    psi[10:13] = 0.5
    assert phasefield.longest_spinodal_run(psi, L) == pytest.approx(5 * L / 40)
    assert phasefield.longest_spinodal_run(np.full(40, 0.5), L) == L


@pytest.mark.parametrize("N", [32, 128])
def test_applicable_is_short_spinodal_runs_and_no_overshoot(N, rng):
    """The run test in LinearizedImplicit.applicable agrees with its definition."""
    L, eps = 2.6442, 0.04
    ch = phasefield.LinearizedImplicit(Spectral(N, L), 1.0, 100.0, eps)
    for trial in range(300):
        psi = np.where(rng.random(N) < 0.5, 0.02, 0.98)
        start, length = rng.integers(N), rng.integers(0, N + 1)
        psi[(start + np.arange(length)) % N] = 0.5                    # one stretch, maybe wrapping
        if trial % 3 == 0:
            psi[rng.integers(N)] = rng.choice([-0.06, 1.06, -0.04])  # overshoots, and one inside the bound
        expected = (psi.min() >= -0.05 and psi.max() <= 1.05
                    and phasefield.longest_spinodal_run(psi, L) <= 2 * np.pi * eps)
        assert ch.applicable(psi) == expected


def test_jacobian_is_the_derivative_of_the_cahn_hilliard_operator(rng):
    N, L, nu, a0, eps = 64, 2.6442, 1.0, 100.0, 0.04
    sp = Spectral(N, L)
    x = L * sp.alpha
    psi = 0.5 + 0.5 * np.tanh((np.abs(x - L / 2) - 0.6) / (2 * np.sqrt(2) * eps))  # two interfaces
    ch = phasefield.LinearizedImplicit(sp, nu, a0, eps)

    def rate(p):   # nu d^2/ds^2 of the psi-dependent part of mu
        return nu * sp.ds2(phasefield.chemical_potential(p, sp.ds2(p), np.zeros(N), 0.0, a0, eps))

    v = np.cos(2 * np.pi * 3 * sp.alpha + 0.4)
    h = 1e-6
    fd = -(rate(psi + h * v) - rate(psi - h * v)) / (2 * h)
    assert np.allclose(ch.jacobian(psi, truncated=False) @ v, fd, rtol=0, atol=1e-6 * np.abs(fd).max())
    assert ch.applicable(psi)                                          # equilibrium-like interfaces
    assert not ch.applicable(np.full(N, 0.5))                          # a spinodal mixture
    explicit = rng.standard_normal(N)
    D1 = np.array([sp.ds(row) for row in np.eye(N)]).T
    J = ch.jacobian(psi)                          # g'' = 1/2 where |g'' - 1/2| <= cutoff
    assert 0 < np.count_nonzero(ch.excess_curvature(psi)) < N // 2       # the low-rank part is small
    for advection in (0.0, -12.0):
        out = ch.solve_linearized(psi, 1500.0, explicit.copy(), advection)
        residual = 1500.0 * out + J @ (out - psi) + advection * (D1 @ out) - explicit
        scale = (np.abs(J).sum(axis=1).max() + 1500.0) * np.abs(out).max()   # ||c I + J|| ||psi||
        assert np.abs(residual).max() < 1e-12 * scale                        # backward stable solve
        dense = np.linalg.solve(1500.0 * np.eye(N) + J + advection * D1, explicit + J @ psi)
        assert np.allclose(out, dense, rtol=0, atol=1e-9 * np.abs(dense).max())
    # The solve keeps int psi ds only up to round-off of J psi* (~ ||J|| eps N ~ 1e-7 here; 1^T J = 0
    # in exact arithmetic); Solver._conserve re-imposes the mass, checked to 1e-12 in test_solver.


def test_named_phase_patterns():
    from hpcves.analysis.pattern import soft_domains

    alpha = np.arange(64) / 64
    one = phasefield.domains_phase(0.48, 0.3, alpha, 1, 0.25)
    assert np.argmax(one) == 16 and abs(one.mean() - 0.48) < 1e-15
    assert soft_domains(one) == [(1, 31)]                  # psi > 1/2 on alpha 0.011-0.489, about 0.25
    assert len(soft_domains(phasefield.domains_phase(0.48, 0.3, alpha, 3, 0.1))) == 3
    solver = make_solver(psi_bar=0.48, delta=0.3, initial_phase="domains", phase_domains=2, phase_center=0.5)
    assert len(soft_domains(solver.initial_state().psi)) == 2


def test_random_phase_patterns_are_reproducible_bit_for_bit_and_the_same_at_every_n():
    a64, a32 = np.arange(64) / 64, np.arange(32) / 32
    seven = phasefield.random_phase(0.5, 0.05, a64, 7)
    assert np.array_equal(seven, phasefield.random_phase(0.5, 0.05, a64, 7))
    assert not np.allclose(seven, phasefield.random_phase(0.5, 0.05, a64, 8))
    assert np.abs(seven[::2] - phasefield.random_phase(0.5, 0.05, a32, 7)).max() < 1e-15
    assert abs(seven.mean() - 0.5) < 1e-15 and np.abs(seven - 0.5).max() <= 4 * 0.05
    spectrum = np.abs(np.fft.rfft(seven - 0.5))
    assert spectrum[1:9].min() > 0 and spectrum[9:].max() < 1e-13          # modes 1-8 only
    first = make_solver(psi_bar=0.5, initial_phase="random", phase_seed=7).initial_state().psi
    assert np.array_equal(first, make_solver(psi_bar=0.5, initial_phase="random", phase_seed=7).initial_state().psi)


def test_phase_pattern_options_are_checked():
    from hpcves.model.params import Case, ConfigError, Physics

    Case(Physics(psi_bar=0.48, delta=0.3, initial_phase="domains"))       # 0.18 ... 0.78
    with pytest.raises(ConfigError, match="initial psi spans"):
        Case(Physics(psi_bar=0.48, delta=0.3))                           # the published pattern: 4 delta
    for bad, message in (({"phase_domains": 0}, "phase_domains = 0"), ({"phase_center": 1.0}, "phase_center = 1.0"),
                         ({"phase_seed": -1}, "phase_seed = -1"), ({"initial_phase": "stripes"}, "initial_phase")):
        with pytest.raises(ConfigError, match=message):
            Physics(**bad)
