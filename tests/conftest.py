"""Shared helpers for the tests; BLAS and OpenMP at one thread, as in a run.

The tiny test campaign lives here: :data:`TINY_RUN` (its numerics and recording) and
:func:`tiny_study` / :func:`write_tiny_study` (a sweep of its cases), used across the campaign,
fault, analysis and dataset tests.
"""
import numpy as np
import pytest

from hpcves.model.params import Case, Numerics, Physics, RunControl
from hpcves.run.runner import one_thread
from hpcves.solver.timestepping import Solver

one_thread()          # BLAS and OpenMP at one thread in this process and its workers (threadpoolctl)


def tiny_run(sample=0.005, snapshot=0.05, checkpoint="{checkpoint}") -> str:
    """The [numerics] and [run] tables of the tiny test cases: N = 32 and dt = 1e-3 (fast), samples,
    snapshots and checkpoints at these intervals of simulated time, none by wall time.
    ``checkpoint`` stays a ``{checkpoint}`` placeholder unless given."""
    return f"""[numerics]
N = 32
dt = 1e-3
[run]
max_spectral_tail = 1.0          # N = 32 on purpose (fast): the resolution watch would stop it
sample_interval = {sample}
snapshot_interval = {snapshot}
checkpoint_interval = {checkpoint}
checkpoint_wall = 0
"""


#: the tiny test cases' numerics and recording, ``{checkpoint}`` filled in by the study
TINY_RUN = tiny_run()


def tiny_study(output, name="tiny", t_end=0.1, checkpoint=0.05, shear="[40, 80]", psi="[0.3, 0.5]", sample=0.005,
               snapshot=0.05, extra="") -> str:
    """The TOML of the tiny test campaign: shear rates ``shear`` x ``psi_bar`` values ``psi`` (None: the
    default psi_bar alone) to ``t_end``, written to ``output``, with ``extra`` tables after its sweep."""
    return (f'[campaign]\nname = "{name}"\noutput = "{output}"\nt_end = {t_end}\n'
            + tiny_run(sample, snapshot, checkpoint) + f"[sweep]\nshear_rate = {shear}\n"
            + (f"psi_bar = {psi}\n" if psi is not None else "") + extra)


def write_tiny_study(directory, name="tiny", output=None, **settings):
    """:func:`tiny_study` written to ``directory/<name>.toml`` (the directory made if need be):
    (study file, campaign file), the campaign file ``directory/<name>.h5`` unless ``output``."""
    directory.mkdir(parents=True, exist_ok=True)
    output = output or directory / f"{name}.h5"
    path = directory / f"{name}.toml"
    path.write_text(tiny_study(output, name, **settings))
    return path, output


def make_solver(N=64, dt=1e-3, **physics):
    return Solver(Case(Physics(**physics), Numerics(N=N, dt=dt), RunControl(t_end=1.0)))


def advance(solver, state, steps):
    for _ in range(steps):
        state, _, _ = solver.step(state)
    return state


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
