"""Shared helpers for the tests; BLAS and OpenMP at one thread, as in a run."""
import numpy as np
import pytest

from hpcves.model.params import Case, Numerics, Physics, RunControl
from hpcves.run.runner import one_thread
from hpcves.solver.timestepping import Solver

one_thread()          # BLAS and OpenMP at one thread in this process and its workers (threadpoolctl)


def make_solver(N=64, dt=1e-3, **physics):
    return Solver(Case(Physics(**physics), Numerics(N=N, dt=dt), RunControl(t_end=1.0)))


def advance(solver, state, steps):
    for _ in range(steps):
        state, _, _ = solver.step(state)
    return state


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
