"""N adapting during a run (numerics.N_max > N; numerics.N = "auto" in a file).

The resolution of a spectral field is read from its tail (spectral.spectral_tail: the
share of the top third of the modes in its variation), for theta_tilde and psi, at
every sample:

* **grow** when either tail passes ``numerics.resize_tail``, to the smallest size of
  :func:`~hpcves.numerics.spectral.fft_sizes` (2^k, 3 2^k, up to N_max) at which the
  spectrum extrapolated along its exponential decay has both tails within
  resize_tail / 4 (spectral.resolution_needed);
* **shrink** one size down (not below the smallest N) when the tails on that smaller
  grid (spectral.tail_on) have stayed within resize_tail / 10 at every sample for
  ``numerics.shrink_after`` shear times; ``State.quiet_since`` keeps since when (NaN: not
  quiet), so a run resumed from a checkpoint decides the same;
* **one size up** when the tension solve finds the shape no longer resolved
  (flow.TensionSolveError, raised by the rates of a state before it is sampled): the
  state is resized and its step taken on the larger grid (:func:`larger_N`); on N_max
  nodes the run stops as under-resolved instead (there is no size up).

A run starts on the smallest size from N up whose start has both tails within
resize_tail (:func:`starting_solver`): a sharp start such as the Delta = 2.3 ellipse (tip
curvature 26) starts finer than one that is nearly round. The watch that stops a run as
under-resolved (run.max_spectral_tail) acts only at N_max.
"""
from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from hpcves.model.params import Case
from hpcves.numerics.spectral import fft_sizes, resolution_needed, spectral_tail, tail_on
from hpcves.solver.timestepping import Solver

#: after growing, the tails are to be within resize_tail / GROW_MARGIN
GROW_MARGIN = 4.0
#: a smaller grid is quiet while its tails stay within resize_tail / SHRINK_MARGIN
SHRINK_MARGIN = 10.0


@functools.lru_cache(maxsize=256)
def sizes(case: Case) -> tuple[int, ...]:
    """The sizes N may take: numerics.N, the FFT-friendly sizes above it below N_max, and N_max."""
    num = case.numerics
    return (num.N,) + tuple(n for n in fft_sizes(num.N + 1, num.N_max - 1)) + (num.N_max,)


def starting_solver(case: Case, start: tuple | None = None) -> Solver:
    """The case's solver on the first of :func:`sizes` whose start (``start``: another state's, as
    Solver takes it) has both tails within resize_tail; on N_max where none has."""
    for n in sizes(case):
        solver = Solver(case, start=start, N=n)
        if max(solver.initial_tails) <= case.numerics.resize_tail:
            return solver
    return solver if solver.sp.N == case.numerics.N_max else Solver(case, start=start, N=case.numerics.N_max)


def tails(theta_hat: np.ndarray, psi_hat: np.ndarray | None, N: int) -> tuple[float, float]:
    """(tail of theta_tilde, tail of psi) from their rffts on N nodes (psi None: homogeneous)."""
    return spectral_tail(theta_hat, N), (0.0 if psi_hat is None else spectral_tail(psi_hat, N))


def grown_N(case: Case, theta_hat: np.ndarray, psi_hat: np.ndarray | None, N: int) -> int:
    """The size to grow to from N, or N when both tails are within resize_tail (or N is N_max)."""
    num = case.numerics
    if N >= num.N_max or max(tails(theta_hat, psi_hat, N)) <= num.resize_tail:
        return N
    larger = [n for n in sizes(case) if n > N]
    target = num.resize_tail / GROW_MARGIN
    needed = max(resolution_needed(f, N, target, largest=math.ceil(num.N_max / N), sizes=larger)
                 for f in (theta_hat, psi_hat) if f is not None)
    return next((n for n in larger if n >= needed), num.N_max)


def larger_N(case: Case, N: int) -> int | None:
    """The next size up from N (None at N_max): where the tension solve finds the shape no longer
    resolved (flow.TensionSolveError), the run goes on one size up."""
    above = [n for n in sizes(case) if n > N]
    return above[0] if above else None


def smaller_N(case: Case, N: int) -> int | None:
    """The next size down from N (None at the smallest)."""
    below = [n for n in sizes(case) if n < N]
    return below[-1] if below else None


def quiet(case: Case, theta_hat: np.ndarray, psi_hat: np.ndarray | None, N: int) -> bool:
    """Whether the next size down would hold both fields within resize_tail / SHRINK_MARGIN."""
    M = smaller_N(case, N)
    if M is None:
        return False
    bound = case.numerics.resize_tail / SHRINK_MARGIN
    return all(tail_on(f, N, M) <= bound for f in (theta_hat, psi_hat) if f is not None)


def next_quiet_since(case: Case, quiet_now: bool, quiet_since: float, t: float) -> float:
    """``State.quiet_since`` after a sample at time t: when the smaller grid became quiet (NaN: it is not)."""
    if not quiet_now:
        return math.nan
    return t if math.isnan(quiet_since) else quiet_since


def shrink_due(case: Case, quiet_since: float, t: float) -> bool:
    """Whether the smaller grid has been quiet for numerics.shrink_after shear times."""
    S = max(case.physics.shear_rate, 1.0)          # below S = 1: time units
    return not math.isnan(quiet_since) and (t - quiet_since) * S >= case.numerics.shrink_after


def decide(case: Case, theta_hat: np.ndarray, psi_hat: np.ndarray | None, N: int, quiet_since: float,
           t: float) -> tuple[int, float]:
    """(the N to go on with, State.quiet_since) after a sample at time t of a state on N nodes whose
    theta_tilde and psi have the rffts ``theta_hat``, ``psi_hat``: grown when a tail passed
    resize_tail, one size down when the smaller grid has been quiet long enough (NaN again after
    any resize). The same answer when asked again of the state it gives (a resumed run asks so)."""
    grown = grown_N(case, theta_hat, psi_hat, N)
    if grown != N:
        return grown, math.nan
    since = next_quiet_since(case, quiet(case, theta_hat, psi_hat, N), quiet_since, t)
    if shrink_due(case, since, t):
        return smaller_N(case, N), math.nan
    return N, since


@functools.lru_cache(maxsize=256)
def _start_N(case: Case) -> int:
    return starting_solver(case).sp.N


def expected_N(case: Case) -> int:
    """The N a case runs at, for planning: numerics.N, or where N adapts the grid its start needs
    (:func:`starting_solver`; numerics.N for a start read from another case's file). Cases that differ
    only in the shear rate start alike: remembered per start."""
    if not case.numerics.adaptive_N:
        return case.numerics.N
    if case.physics.initial_shape == "stored":
        return case.numerics.N
    physics = dataclasses.replace(case.physics, shear_rate=1.0)
    return _start_N(dataclasses.replace(case, physics=physics))
