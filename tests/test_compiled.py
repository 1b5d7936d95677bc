"""The compiled engine (solver/compiled.py) against the numpy path it fuses: the same rates and the same
steps to round-off, on every branch of a step, and the same errors."""
import dataclasses

import numpy as np
import pytest

from hpcves.model.flow import TensionSolveError
from hpcves.model.params import Case, Numerics, Physics, RunControl
from hpcves.solver.timestepping import Solver, State


def case(N=64, dt=1e-3, rtol=None, numerics=None, **physics):
    physics = {"psi_bar": 0.3, "shear_rate": 80.0, **physics}
    steps = {"rtol": rtol} if rtol else {"dt": dt}
    return Case(Physics(**physics), Numerics(N=N, **steps, **(numerics or {})), RunControl(t_end=10.0))


def pair(c):
    return Solver(c, engine="numpy"), Solver(c, engine="compiled")


def relative(a, b):
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / max(np.max(np.abs(np.asarray(b))), 1e-300))


def contiguous(value, names=State.ARRAYS):
    """``value`` (a State, or Rates with names theta and psi) with those arrays contiguous, as the compiled
    engine's own are: the numpy engine's theta_t is a strided imaginary part, for which numba would
    compile the step once more."""
    return dataclasses.replace(value, **{n: np.ascontiguousarray(getattr(value, n)) for n in names
                                         if getattr(value, n) is not None})


def advanced(solver, steps, k=None):
    state = solver.initial_state()
    for _ in range(steps):
        state, _, _ = solver.step(state, k=k)
    return state


def test_the_default_engine_is_compiled_with_fftw_and_numpy_with_numpy_transforms():
    c = case()
    assert Solver(c).engine == "compiled"
    assert Solver(c, fft_backend="numpy").engine == "numpy"
    assert Solver(c).at(96).engine == "compiled"
    with pytest.raises(ValueError, match="unknown engine"):
        Solver(c, engine="fortran")


@pytest.mark.parametrize("physics", [
    dict(),                                                  # two-phase, saturating law
    dict(bending_law="linear"),
    dict(psi_bar=0.0, shear_rate=10.0),                      # homogeneous
    dict(psi_bar=0.48, excess_length=2.3, shear_rate=5.0),   # deflated: sharp tips, tension refined
], ids=["two-phase", "linear-law", "homogeneous", "deflated"])
def test_rates_agree_to_round_off(physics):
    numpy_solver, compiled_solver = pair(case(**physics))
    state = advanced(numpy_solver, 30)
    # psi pushed past [0, 1] where it is not homogeneous: the saturating law's outer branch and B''
    if state.psi.std() > 0:
        state = dataclasses.replace(state, psi=1.06 * state.psi - 0.03)
    a, b = compiled_solver.rates(state), numpy_solver.rates(state)
    for name in ("theta", "psi", "psi_s"):
        assert relative(getattr(a, name), getattr(b, name)) < 1e-11, name
    assert relative(a.flow.velocity, b.flow.velocity) < 1e-12
    assert relative(a.flow.tension_eff, b.flow.tension_eff) < 1e-11
    assert abs(a.center - b.center) < 1e-12 * max(1.0, abs(b.center))
    assert abs(a.mean_tangential_velocity - b.mean_tangential_velocity) < 1e-12 * abs(b.flow.velocity).max()
    for name in ("z", "tangent", "curvature"):
        assert relative(getattr(a.shape, name), getattr(b.shape, name)) < 1e-13, name
    if b.mu is None:
        assert a.mu is None and a.psi_hat is None
    else:
        assert relative(a.mu, b.mu) < 1e-11 and relative(a.psi_hat, b.psi_hat) < 1e-13


@pytest.mark.parametrize("numerics, rtol", [
    ({}, None),                                      # fixed steps: w = 1
    ({}, 1e-2),                                      # adaptive: w != 1, rejections
    ({"area_correction": False}, None),              # closure only
], ids=["fixed", "adaptive", "no-area-correction"])
def test_steps_agree_to_round_off(numerics, rtol):
    numpy_solver, compiled_solver = pair(case(rtol=rtol, numerics=numerics))
    state = advanced(numpy_solver, 40, k=None if rtol is None else 2e-4)
    k = None if rtol is None else 3e-4                      # a step ratio of 1.5
    for quadratic in (False, True):
        start = contiguous(state if quadratic else dataclasses.replace(state, prev2_theta=None, prev2_psi=None))
        rates = contiguous(numpy_solver.rates(start), ("theta", "psi"))
        (a, _, ea), (b, _, eb) = compiled_solver.step(start, rates, k), numpy_solver.step(start, rates, k)
        assert relative(a.theta, b.theta) < 1e-12 and relative(a.psi, b.psi) < 1e-12
        assert abs(a.center - b.center) < 1e-14 and abs(a.shift - b.shift) < 1e-14
        assert abs(a.area_correction - b.area_correction) < 1e-14
        assert ea.order == eb.order == (3 if quadratic else 2)
        # the estimates are differences of nearly equal levels: compared against the levels
        assert np.max(np.abs(ea.theta - eb.theta)) < 1e-12 * np.max(np.abs(b.theta))
        assert np.max(np.abs(ea.psi - eb.psi)) < 1e-12
        assert ea.scale_theta == pytest.approx(eb.scale_theta, rel=1e-13)
        assert ea.scale_psi == pytest.approx(eb.scale_psi, rel=1e-13)


def test_the_stabilised_euler_fallback_agrees():
    """Early in the spinodal stage the linearly implicit step is not applicable: both engines take the
    stabilised Euler step (its estimate kept to the followed modes)."""
    numpy_solver, compiled_solver = pair(case(psi_bar=0.5, shear_rate=0.0, dt=2e-5))
    state = contiguous(advanced(numpy_solver, 3))
    assert not numpy_solver.cahn_hilliard.applicable(state.psi)
    rates = contiguous(numpy_solver.rates(state), ("theta", "psi"))
    (a, _, ea), (b, _, eb) = compiled_solver.step(state, rates), numpy_solver.step(state, rates)
    assert relative(a.psi, b.psi) < 1e-12 and relative(a.theta, b.theta) < 1e-12
    assert np.max(np.abs(ea.psi - eb.psi)) < 1e-12


def test_trajectories_agree_over_a_thousand_steps():
    """Round-off only: after t = 1 of phase treading (S = 80) the engines differ by ~1e-12."""
    numpy_solver, compiled_solver = pair(case())
    a, b = advanced(compiled_solver, 1000), advanced(numpy_solver, 1000)
    assert relative(a.theta, b.theta) < 1e-9 and relative(a.psi, b.psi) < 1e-9
    assert abs(a.center - b.center) < 1e-9


def test_an_unresolved_shape_raises_as_the_numpy_path_does():
    numpy_solver, compiled_solver = pair(case(N=32))
    state = numpy_solver.initial_state()
    rough = np.random.default_rng(1).standard_normal(32)
    broken = dataclasses.replace(state, theta=state.theta + 1.5 * rough)
    errors = []
    for solver in (numpy_solver, compiled_solver):
        with pytest.raises(TensionSolveError) as error:
            solver.rates(broken)
        errors.append(str(error.value))
    assert all("no longer resolved" in e for e in errors), errors


@pytest.mark.parametrize("physics", [dict(), dict(psi_bar=0.0, shear_rate=10.0),
                                     dict(psi_bar=0.48, excess_length=2.3, shear_rate=5.0)],
                         ids=["two-phase", "homogeneous", "deflated"])
def test_a_sample_agrees_with_the_numpy_diagnostics(physics):
    from hpcves.run import diagnostics

    numpy_solver, compiled_solver = pair(case(**physics))
    state = advanced(numpy_solver, 300)
    rates = numpy_solver.rates(state)
    a, b = diagnostics.sample(compiled_solver, state, rates), diagnostics.sample(numpy_solver, state, rates)
    assert a.keys() == b.keys()
    for name in b:
        if name == "stretching":           # a residual at round-off: compared against the velocities
            assert abs(a[name] - b[name]) < 1e-12 * np.abs(rates.flow.velocity).max()
            continue
        y = np.asarray(b[name], dtype=float)
        scale = max(1.0, float(np.max(np.abs(y)))) if np.all(np.isfinite(y)) else 1.0
        np.testing.assert_allclose(a[name], b[name], rtol=0, atol=1e-11 * scale, err_msg=name)   # NaN = NaN


def test_the_health_check_names_the_same_non_finite_array_and_psi_range():
    from hpcves.run import diagnostics

    numpy_solver, compiled_solver = pair(case())
    state = advanced(numpy_solver, 3)
    for name in ("theta", "psi", "prev_rate_theta", "prev_rate_psi"):
        broken = getattr(state, name).copy()
        broken[5] = np.nan if name != "psi" else np.inf
        bad = dataclasses.replace(state, **{name: broken})
        a, b = diagnostics.health(compiled_solver, bad, None), diagnostics.health(numpy_solver, bad, None)
        assert not a.ok and a.reason == b.reason and name in a.reason
    high = dataclasses.replace(state, psi=state.psi + 2.0)
    a, b = diagnostics.health(compiled_solver, high, None), diagnostics.health(numpy_solver, high, None)
    assert not a.ok and a.reason == b.reason and "psi left" in a.reason
    assert diagnostics.health(compiled_solver, state, None).ok
