"""The stress a vesicle adds to the suspension (model/rheology.py; issue 66): the stresslet against the
two-dimensional rigid-ellipse solution as the viscosity ratio grows, against the far field of the
flow it makes (each term alone), and as recorded series of a run in either engine."""
import dataclasses

import numpy as np
import pytest

from conftest import advance, make_solver
from hpcves.analysis.stress import settled_mean
from hpcves.model import flowfield, geometry, rheology
from hpcves.model.forces import bending_force, tension_force
from hpcves.run import diagnostics


def _force(solver, state, rates):
    shape, sp = rates.shape, solver.sp
    return bending_force(shape.curvature, state.psi, rates.psi_s, shape.tangent, solver.case.physics, sp) \
        + tension_force(rates.flow.tension_eff, shape.tangent, sp)


def _coefficients_at(viscosity_ratio, turn, shear_rate=2.0):
    """([eta], N1) of the initial 1/2 : 1/3 ellipse turned by ``turn``, from its rates at t = 0, and the
    rigid ellipse's at the same inclination (semi-axes from the second moments)."""
    solver = make_solver(N=64, dt=1e-4, shear_rate=shear_rate, viscosity_ratio=viscosity_ratio)
    state = solver.initial_state()
    state = dataclasses.replace(state, theta=state.theta + turn)
    rates = solver.rates(state)
    shape = rates.shape
    row = diagnostics.stress(solver, state, rates, geometry.moments(shape.z, shape.normal, solver.sp.length).area)
    m = geometry.moments(shape.z, shape.normal, solver.sp.length)
    small, large = np.linalg.eigvalsh([[m.Ixx, m.Ixy], [m.Ixy, m.Iyy]])
    a, b = 2 * np.sqrt(large / m.area), 2 * np.sqrt(small / m.area)      # I = A a^2 / 4 along an axis
    assert abs(a - 0.5) < 1e-4 and abs(b - 1 / 3) < 1e-4      # N = 64 nodes trace the ellipse to ~1e-5
    measured = np.array([row["intrinsic_viscosity"], row["normal_stress_coefficient"]])
    return measured, np.array(rheology.rigid_ellipse(a, b, m.inclination))


def test_a_rigid_disk_has_einsteins_two_dimensional_coefficient_and_no_normal_stress():
    eta, n1 = rheology.rigid_ellipse(0.4, 0.4, np.linspace(-1.5, 1.5, 7))
    assert np.allclose(eta, 2.0, rtol=0, atol=1e-15) and np.allclose(n1, 0.0, rtol=0, atol=1e-15)


@pytest.mark.parametrize("turn", [0.0, 0.3, 0.7, -0.4])
def test_a_very_viscous_vesicle_approaches_the_rigid_ellipse_as_one_over_lambda(turn):
    """As lambda grows the vesicle's interior cannot flow, and the stresslet tends to a rigid body's:
    the gap falls tenfold per tenfold lambda (its O(1/lambda) term: measured 2.0e-3, 2.0e-4 in [eta]
    at theta = 0.3), and extrapolated in 1/lambda it meets the analytic values to 3e-7."""
    (m3, rigid), (m4, _) = _coefficients_at(1e3, turn), _coefficients_at(1e4, turn)
    gap3, gap4 = np.abs(m3 - rigid), np.abs(m4 - rigid)
    for k in range(2):
        if gap3[k] > 1e-9:                                  # N1 = 0 at theta = 0 to round-off
            assert 8.0 < gap3[k] / gap4[k] < 12.0, (k, gap3, gap4)
    extrapolated = (10.0 * m4 - m3) / 9.0
    assert np.abs(extrapolated - rigid).max() < 1e-6, (extrapolated, rigid)     # measured <= 3e-7
    assert rigid[0] > 1.9                                   # positive, near the disk's 2: the sign is right


def _far_field_stresslet(solver, state, rates, force, radius=800.0, n=64):
    """(Sigma_xy, Sigma_xx - Sigma_yy) read off the disturbance flow on a circle of ``radius`` about
    the vesicle: a force-free, torque-free membrane's far field is u_i = -(1/2 pi) x_i (x . Sigma . x) / r^4
    (the two-dimensional Stokeslet's gradient contracted with the stresslet), up to O(1/r^2)."""
    phys, shape = solver.case.physics, rates.shape
    centre = geometry.moments(shape.z, shape.normal, solver.sp.length).centroid
    phi = 2 * np.pi * np.arange(n) / n
    x = centre + radius * np.exp(1j * phi)
    u = flowfield.velocity(x, shape.z, force, rates.flow.velocity, phys.shear_rate, phys.viscosity_ratio) \
        - phys.shear_rate * x.imag
    radial = -2 * np.pi * radius * np.real(u * np.exp(-1j * phi))         # = x^ . Sigma . x^
    return 2 * np.mean(radial * np.sin(2 * phi)), 4 * np.mean(radial * np.cos(2 * phi))


@pytest.mark.parametrize("viscosity_ratio", [1.0, 4.0, 0.2])
def test_the_stresslet_is_what_the_far_field_of_the_flow_says_term_by_term(viscosity_ratio):
    """The force term alone (the single layer of f, velocity field with lambda = 1) and the contrast term
    alone (f = 0: only the double layer of u) each match their far field; and so does their sum."""
    solver = make_solver(N=64, dt=1e-4, shear_rate=5.0, psi_bar=0.3, viscosity_ratio=viscosity_ratio)
    state = advance(solver, solver.initial_state(), 40)
    rates = solver.rates(state)
    shape, sp = rates.shape, solver.sp
    force = _force(solver, state, rates)
    parts = {"sum": (force, viscosity_ratio)}
    if viscosity_ratio != 1.0:
        parts["contrast alone"] = (0 * force, viscosity_ratio)
    for name, (f, lam) in parts.items():
        surface = np.array(rheology.stresslet(shape.z, shape.normal, f, rates.flow.velocity, sp.length, lam))
        far = np.array(_far_field_stresslet(solver, state, rates, f))
        assert np.abs(surface - far).max() < 1e-5 * np.abs(surface).max(), (name, surface, far)
        assert np.abs(surface).min() > 1e-2                     # both components are there to compare


def test_the_series_are_recorded_in_both_engines_and_agree():
    rows = {}
    for engine in ("numpy", "compiled"):
        solver = make_solver(N=64, dt=5e-4, shear_rate=20.0, psi_bar=0.3, viscosity_ratio=3.0)
        solver = type(solver)(solver.case, engine=engine)
        state = advance(solver, solver.initial_state(), 30)
        rows[engine] = diagnostics.sample(solver, state, solver.rates(state))
    for name in diagnostics.RHEOLOGY_SERIES:
        assert np.isfinite(rows["numpy"][name]), name
        assert abs(rows["numpy"][name] - rows["compiled"][name]) <= 1e-9 * abs(rows["numpy"][name]), name
    area = rows["numpy"]["stresslet_xy"] / rows["numpy"]["intrinsic_viscosity"] / 20.0
    assert abs(area - np.pi * 0.5 / 3) < 1e-4 * area            # A = pi a b of the initial ellipse


def test_a_settled_mean_is_taken_over_whole_periods_and_its_bar_covers_the_truth():
    """A periodic series averaged over the last whole periods of theta's period: no bias from a
    fraction of one; a steady one over the settled part; the bar covers the true mean."""
    T = 0.37
    t = np.arange(0.0, 5.0, T / 40.3)                         # the samples do not divide the period
    x = 1.8 + 0.05 * np.sin(2 * np.pi * t / T + 0.4) + 0.3 * np.exp(-t / 0.2)   # a transient, then periodic
    found = settled_mean(t, x, 1.5, T, 1e-6)
    assert abs(found.mean - 1.8) <= found.error and found.error < 2e-3
    assert found.amplitude == pytest.approx(0.05, rel=0.01)
    naive = x[t >= 1.5].mean()                               # every settled sample: a part period biases it
    assert abs(naive - 1.8) > abs(found.mean - 1.8)
    steady = settled_mean(t, 1.9 + 1e-9 * np.random.default_rng(1).normal(size=t.size), 1.0)
    assert abs(steady.mean - 1.9) <= steady.error < 1e-7 and steady.amplitude < 1e-8
    assert np.isnan(settled_mean(t[:5], x[:5], 0.0).mean)        # too few samples: none


def test_the_stress_error_bars_follow_the_measured_rule_and_are_absent_where_it_does_not_hold():
    from hpcves.analysis import accuracy
    eta = "intrinsic_viscosity"
    assert accuracy.stress_step_error(eta, 1e-3) == pytest.approx(accuracy.STRESS_PER_RTOL[eta] * 1e-3)
    assert accuracy.stress_grid_error(eta, 1e-4) == pytest.approx(accuracy.STRESS_PER_TAIL[eta] * 1e-4)
    assert np.isnan(accuracy.stress_step_error(eta, None))                        # a fixed step
    assert np.isnan(accuracy.stress_step_error(eta, 1e-3, flips=True))            # tumbling
    assert np.isnan(accuracy.stress_grid_error(eta, 2 * accuracy.TAIL_RULED_UP_TO))   # beyond the watch
    assert np.isnan(accuracy.stress_grid_error(eta, float("nan")))               # a record without the tails
