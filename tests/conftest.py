"""Shared helpers for the tests. hpcves is imported first so that it pins BLAS to one thread."""
import hpcves  # noqa: F401  (sets the BLAS thread defaults before numpy loads)
import numpy as np
import pytest

from hpcves.model.params import Case, Numerics, Physics, RunControl
from hpcves.run.timestepping import Solver


def make_solver(N=64, dt=1e-3, **physics):
    return Solver(Case(Physics(**physics), Numerics(N=N, dt=dt), RunControl(t_end=1.0)))


def advance(solver, state, steps):
    for _ in range(steps):
        state, _, _ = solver.step(state)
    return state


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
