"""Step-size control for the variable-step SBDF2 scheme: error norm, PI controller, rejection.

Pure functions of numbers (and of the solver's step, for :func:`advance`).

Error norm. A step leaves y^{n+1} - p per field (timestepping.Estimate), p
the quadratic through the last three levels, ~ C k^3 y_ttt like the scheme's
own local error. Each field (theta_tilde, the tangent angle's departure from a
circle, and psi) is measured in the max norm over the nodes, against its
tolerance eps_f = atol + rtol * scale_f, scale_f = max(|y^n|_inf, |y^{n+1}|_inf),
and the norm is the larger of the two:

    err = max_f  |y_f^{n+1} - p_f|_inf / (eps_f * sqrt(rtol)).

A step is accepted when err <= 1: each step's local error is held below
eps_f sqrt(rtol), ~ rtol^{3/2} scale_f. Holding the local error per step to a
fixed bound equidistributes it, which is what minimises the steps for a given
global error of a second-order method; the bound's power 3/2 = (p + 1)/p makes
the global error proportional to rtol (tolerance proportionality, Hairer,
Norsett & Wanner, Solving ODEs I, II.4). Measured in docs/numerics.md. The
centre and the material shift do not enter: neither feeds back into the
shape or the phase.

Controller (PI, Gustafsson 1991; Hairer & Wanner, Solving ODEs II, IV.2,
eq. 2.43c). With err ~ k^q (q = 3; q = 2 for the first two steps, whose
estimates are of lower order),

    k_{n+1} = k_n * safety * err_n^(-0.7/q) * err_{n-1}^(0.4/q),

the factor clipped to [min_factor, max_factor]. max_factor = 2 keeps the step
ratio inside the zero-stability bound 1 + sqrt 2 of variable-step BDF2. A
rejected step is retried from the same level with k * max(min_factor,
safety * err^(-1/q)), and after a second rejection in a row with
k * min_factor: err ~ k^q holds for a smooth solution and a history of
similar steps, but right after a sharp change the estimate of a multistep
step falls only about in proportion to k (its predictor's slope at t_n comes
from the last steps), and a k^q retry shrinks it too little (docs/numerics.md,
"Adaptive time step"). The step after a rejection does not grow. The first step
(Richardson-extrapolated IMEX Euler) starts from ``initial_dt`` and the same
controller grows it: the spinodal start-up, where psi separates on time
scales ~ eps / (nu a0 g''^2) ~ 1e-4, is taken in small steps because the
estimate asks for them, not by a special rule.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from hpcves.numerics.reductions import largest_magnitude


@dataclass(frozen=True)
class StepControl:
    """Tolerances and limits of the controller (see the module docstring)."""

    rtol: float
    atol: float = 0.0
    dt_max: float = math.inf
    dt_min: float = 1e-12
    initial_dt: float = 1e-6
    safety: float = 0.9
    max_factor: float = 2.0
    min_factor: float = 0.2
    max_rejections: int = 20

    def __post_init__(self) -> None:
        if not 0 < self.max_factor < 1.0 + math.sqrt(2.0):
            raise ValueError(f"max_factor = {self.max_factor}: variable-step BDF2 is zero-stable "
                             "only for step ratios below 1 + sqrt 2")


#: a step may be stretched by this factor to land on an event instead of taking two
STRETCH = 1.1


class StepSizeError(ArithmeticError):
    """The controller could not find an acceptable step above ``dt_min``."""


def error_norm(estimate, control: StepControl) -> float:
    """max over fields of |y^{n+1} - p|_inf / ((atol + rtol * scale) sqrt(rtol)); inf if anything is not finite."""
    fields = [(estimate.theta, estimate.scale_theta)]
    if estimate.psi is not None:
        fields.append((estimate.psi, estimate.scale_psi))
    worst = 0.0
    root = math.sqrt(control.rtol)
    for difference, scale in fields:
        weight = control.atol + control.rtol * scale
        if not weight > 0:
            weight = control.rtol            # a field identically zero: measure absolutely
        weight *= root
        value = float(largest_magnitude(difference)) / weight
        if not math.isfinite(value):
            return math.inf
        worst = max(worst, value)
    return worst


def next_step(k: float, err: float, err_prev: float, control: StepControl, q: int = 3) -> float:
    """The PI proposal after an accepted step of length k with error err ~ k^q (err_prev: the step before)."""
    err = max(err, 1e-10)
    factor = control.safety * err ** (-0.7 / q)
    if math.isfinite(err_prev) and err_prev > 0:
        factor *= max(err_prev, 1e-10) ** (0.4 / q)
    factor = min(control.max_factor, max(control.min_factor, factor))
    return min(control.dt_max, k * factor)


def retry_step(k: float, err: float, control: StepControl, q: int = 3) -> float:
    """The step to retry with after a rejection (err > 1, possibly inf; err ~ k^q)."""
    factor = control.min_factor if not math.isfinite(err) else \
        max(control.min_factor, control.safety * err ** (-1.0 / q))
    return k * min(factor, 0.9)


def fit_to(t: float, k: float, t_event: float) -> tuple[float, bool]:
    """(step, lands): k shortened so that steps meet t_event exactly without a tiny last one.

    If t + STRETCH k reaches t_event, the step is t_event - t and lands on it (a
    step at most 10 % longer than proposed: inside the safety factor). If two
    steps of k reach it, the step is half the gap (two equal steps, no tiny last
    one). Farther away the step is k; neither of these lands.
    """
    gap = t_event - t
    if STRETCH * k >= gap:
        return gap, True
    count = math.ceil(gap / k)
    if count == 2:
        return 0.5 * gap, False
    return k, False


@dataclass(frozen=True)
class Taken:
    """An accepted step: the new state and what the controller did to get it."""

    state: object
    error: float
    rejections: int


def advance(solver, state, rates, k: float, control: StepControl, t_event: float) -> Taken:
    """One accepted step from ``state`` (whose ``rates`` are given), at most up to ``t_event``.

    ``k`` is the proposed step. The returned state carries ``error`` (its err)
    and ``dt_next`` (the proposal for the step after it), which is all the
    controller remembers: a checkpoint of the state resumes it exactly.
    """
    rejections = 0
    while True:
        step, lands = fit_to(state.t, k, t_event)
        if step < control.dt_min:
            raise StepSizeError(f"the step size fell to {step:.3g} (below {control.dt_min:g}) at "
                                f"t = {state.t:.6g} after {rejections} rejections: the tolerance cannot "
                                "be met (a singularity forming?)")
        new, _, estimate = solver.step(state, rates, step)
        err = error_norm(estimate, control)
        if err <= 1.0:
            break
        rejections += 1
        if rejections > control.max_rejections:
            raise StepSizeError(f"{rejections} rejected steps in a row at t = {state.t:.6g} "
                                f"(last error estimate {err:.3g} of the tolerance, step {step:.3g})")
        # the first retry trusts err ~ k^q; a second rejection in a row means it does not hold here
        # (after a sharp change the estimate falls only ~ k, the history's part of it not at all)
        k = retry_step(step, err, control, estimate.order) if rejections == 1 else step * control.min_factor
    proposal = next_step(step, err, state.error, control, estimate.order)
    if rejections:
        proposal = min(proposal, step)
    return _accepted(new, err, proposal, t_event if lands else None, rejections)


def fixed(solver, state, rates, k: float, control: StepControl, t_event: float) -> Taken:
    """One step of ``k`` from ``state`` (cut to land on ``t_event`` as :func:`fit_to` cuts), accepted whatever
    its error: a fixed-step stretch of an adaptive run. The state carries its err and the controller's
    proposal as :func:`advance` leaves them, so the controller takes over from it where the stretch ends."""
    step, lands = fit_to(state.t, k, t_event)
    new, _, estimate = solver.step(state, rates, step)
    err = error_norm(estimate, control)
    proposal = next_step(step, err, state.error, control, estimate.order) if math.isfinite(err) else step
    return _accepted(new, err, proposal, t_event if lands else None, 0)


def _accepted(new, err: float, proposal: float, landed: float | None, rejections: int) -> Taken:
    """``new`` as accepted: its err and the proposal for the next step recorded, its t set to the event
    ``landed`` on (None: it landed on none)."""
    if landed is not None:
        return Taken(_replaced(new, t=landed, error=err, dt_next=proposal), err, rejections)
    return Taken(_replaced(new, error=err, dt_next=proposal), err, rejections)


def _replaced(state, **changes):
    """dataclasses.replace(state, **changes) for a dataclass without __post_init__ or slots (the
    solver's State): its attributes copied, ``changes`` set -- 1.5 us against 15 a step."""
    new = object.__new__(type(state))
    vars(new).update(vars(state))
    vars(new).update(changes)
    return new
