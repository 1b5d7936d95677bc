"""Longer physics checks (SPEC 6.3, 6.5): ``pytest -m slow`` / ``make validate``."""
import numpy as np
import pytest

from conftest import make_solver
from hpcves.analysis.periodicity import crossing_period
from hpcves.model import geometry
from hpcves.run import diagnostics

pytestmark = pytest.mark.slow


def theta_series(solver, t_end, every):
    state = solver.initial_state()
    t, theta, lab = [], [], []
    for n in range(round(t_end / solver.dt) + 1):
        if n % every == 0:
            rates = solver.rates(state)
            row = diagnostics.sample(solver, state, rates)
            t.append(row["t"])
            theta.append(row["theta"])
            lab.append(row["V_psi"] + row["V_L"])
            state, _, _ = solver.step(state, rates)
        else:
            state, _, _ = solver.step(state)
    return np.array(t), np.array(theta), np.array(lab)


def test_psi03_tank_treads_at_S40_and_phase_treads_at_S80():
    t, theta, lab = theta_series(make_solver(N=128, dt=5e-4, shear_rate=40.0, psi_bar=0.3), 2.0, 4)
    late = t > 1.0
    assert np.ptp(theta[late]) < 1e-3                       # steady inclination
    assert np.abs(lab[late]).max() < 0.05                   # phase pattern fixed in the lab frame
    t, theta, lab = theta_series(make_solver(N=128, dt=5e-4, shear_rate=80.0, psi_bar=0.3), 2.0, 4)
    p = crossing_period(t, theta, t_start=1.0)
    assert p.amplitude > 0.01 and theta[t > 1.0].min() > 0  # oscillates, no flip: phase-treading
    assert p.period == pytest.approx(0.1733, rel=0.01)      # converged value (BENCHMARKS.md)
    assert p.spread < 1e-3 * p.period                        # periodic


def test_homogeneous_angle_is_the_same_at_S350():
    def settled(S, dt, t_end):
        solver = make_solver(N=64, dt=dt, shear_rate=S, psi_bar=0.0)
        state = solver.initial_state()
        for _ in range(round(t_end / dt)):
            state, _, _ = solver.step(state)
        shape = solver.shape(state)
        return geometry.moments(shape.z, shape.normal, solver.sp.length).inclination
    assert settled(350.0, 1e-4, 0.3) == pytest.approx(settled(2.0, 1e-3, 8.0), abs=0.01)


def test_the_discretisation_error_bar_covers_the_period_and_inclination_error():
    """hpcves/analysis/accuracy.py's rule on the period table's fastest case (psi_bar = 0.3, S = 320) at sparse
    sampling (the controller alone sets the step), against rtol = 1e-4 (docs/error_rule.md)."""
    import sys
    from pathlib import Path

    from hpcves.analysis import accuracy

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "analysis"))
    import error_rule

    reference = error_rule.run("PT a", "sparse", 1e-4)
    for rtol in (1e-1, 1e-2):
        r = error_rule.run("PT a", "sparse", rtol)
        # the whole error bar (statistical, of both estimates, + discretisation) covers the difference
        stat = r["period_err"] + reference["period_err"]
        assert abs(r["period"] - reference["period"]) <= stat + accuracy.period_error(r["period"], rtol), (rtol, r)
        stat = r["mean_err"] + reference["mean_err"]
        assert abs(r["mean"] - reference["mean"]) <= stat + accuracy.inclination_error(r["mean"], rtol), (rtol, r)
