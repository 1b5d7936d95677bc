"""Drive one case: step, sample, snapshot, checkpoint, stop cleanly.

Everything here is deterministic in the state -- samples, snapshots and
checkpoints when the clock (schedule.py: whole steps for a fixed dt, simulated
time for an adaptive one) says so, plus extra checkpoints on a wall-clock timer
and on request, which read the state but never change it; the step controller's
memory is part of the state -- so a run resumed from any checkpoint reproduces
the uninterrupted one bit for bit.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
from threadpoolctl import threadpool_limits

from hpcves.run import decision
from hpcves.run import diagnostics
from hpcves.files import faults
from hpcves.run import schedule
from hpcves.run import store as checkpoint_module
from hpcves.run.store import FAILED, FINISHED, INTERRUPTED, MODEL_LIMIT, RUNNING, CaseStore
from hpcves.model.flow import TensionSolveError
from hpcves.analysis.regimes import AnalysisSettings
from hpcves.run.timestepping import Solver, State

#: psi beyond [-OVERSHOOT, 1 + OVERSHOOT] when a run under the linear bending law gives out: the
#: model's limit, not a failure (healthy steps stay within 0.005 of [0, 1]; beyond_model)
OVERSHOOT = 0.03

#: write buffered samples at least this often (seconds), so that a running case can be watched
SAMPLE_FLUSH_SECONDS = 10.0
SAMPLE_BUFFER_ROWS = 512


@dataclass(frozen=True)
class Outcome:
    status: int          # checkpoint.FINISHED / FAILED / MODEL_LIMIT / INTERRUPTED
    message: str
    t: float
    steps: int           # steps taken in this call
    wall: float          # seconds spent in this call


@dataclass(frozen=True)
class Tick:
    """What a progress display gets, about twice a second."""

    t: float
    t_end: float
    steps_per_second: float
    eta_seconds: float
    theta: float


class Diverged(RuntimeError):
    pass


class UnderResolved(Diverged):
    """N is too small for the shape or the phase field (the spectral tail watch)."""


#: how a model-limit stop's message begins, and what follows its cause (model_limit_cause)
MODEL_LIMIT_PREFIX, STOPPED_BY = "model limit: ", "; the run stopped "


def model_limit_cause(message: str) -> str:
    """Why a case reached the model's limit (its message without the prefix and the failure it caused)."""
    return message.removeprefix(MODEL_LIMIT_PREFIX).split(STOPPED_BY)[0]


def beyond_model(state: State, bending_law: str = "linear") -> str:
    """Why a run that gives out has reached the limit of its model, or "" if it has not.

    Under the linear bending law B(psi) = B1 + (B2 - B1) psi, which reaches zero at
    psi = B1 / (B1 - B2), the energy (a0/eps) g(psi) + B(psi) H^2 / 2 is unbounded below at
    high curvature once psi leaves [0, 1]: the soft phase gathers at a tip that sharpens
    without end (docs/numerics.md, "Bending law"). psi beyond [-OVERSHOOT, 1 + OVERSHOOT]
    over the last levels is that; the saturating law is bounded there, so its failures are
    failures.
    """
    if bending_law != "linear":
        return ""
    levels = [p for p in (state.psi, state.prev_psi, state.prev2_psi) if p is not None]
    lo, hi = min(float(p.min()) for p in levels), max(float(p.max()) for p in levels)
    if lo >= -OVERSHOOT and hi <= 1.0 + OVERSHOOT:
        return ""
    return (f"psi in [{lo:.4g}, {hi:.4g}] over the last steps, beyond [0, 1] (healthy steps stay within "
            "0.005 of it), where the linear bending law B(psi) nears zero: the model, not the numerics, gives "
            'out (bending_law = "saturating" is bounded there; docs/numerics.md)')


def one_thread():
    """The thread pools of every loaded BLAS and OpenMP library at one thread while the returned
    context lasts (threadpoolctl; applied at once, also without ``with``). The matrices of a case
    are ~100 x 100, where threads only cost: spin-waits of a few milliseconds per call were measured
    with OpenBLAS on two cores, and one case runs on one core (a campaign runs one per rank)."""
    return threadpool_limits(limits=1)


def run(store: CaseStore, flush: Callable[[], None], *, resume: bool = False,
        progress: Callable[[Tick], None] | None = None,
        stop_requested: Callable[[], bool] = lambda: False,
        max_steps: int | None = None, analysis: AnalysisSettings = AnalysisSettings()) -> Outcome:
    """Run (or continue) the case in ``store`` to its end time (or, with run.until_decided, until
    decided by the classification with the thresholds ``analysis``: decision.py).

    ``flush`` makes the file durable (h5py File.flush). ``stop_requested`` is
    polled every step; when it returns True the current state is checkpointed
    and the run returns as INTERRUPTED. ``max_steps`` stops after that many
    steps in this call, the same way (for tests and for time-sliced work).
    BLAS and OpenMP run on one thread meanwhile (:func:`one_thread`).
    """
    with one_thread():
        return _run(store, flush, resume, progress, stop_requested, max_steps, analysis)


def _run(store, flush, resume, progress, stop_requested, max_steps, analysis) -> Outcome:
    case = store.case
    solver = Solver(case)
    state = None
    wall_before = 0.0                  # wall time of earlier calls on this case
    if resume:
        wall_before = float(np.nan_to_num(store.progress[2]))
        found = store.read_checkpoint()
        if found is not None:
            state, n_samples, n_snapshots = found
            store.truncate(n_samples, n_snapshots)
    if state is None:
        state = solver.initial_state()
        store.truncate(0, 0)
    deciding = case.run.until_decided
    if deciding:          # what the decisions read: every sample so far (the same numbers after a resume)
        recorded = store.timeseries()
        history = {name: list(recorded[name]) for name in decision.SERIES}
    store.set_decision(*checkpoint_module.NOT_DECIDED)

    clock = schedule.clock(case)
    wall_interval = case.run.checkpoint_wall

    store.set_status(RUNNING, "", "")
    flush()
    start_wall = last_checkpoint_wall = last_flush_wall = last_tick = time.perf_counter()
    start_step, start_fraction = state.step, clock.fraction(state)
    rows: list[dict] = []
    theta_now = np.nan
    last_correction = 0.0          # relative area correction made by the last step

    def write_rows(s: State | None = None):
        """Write buffered samples (and, given the current state, the progress)."""
        nonlocal last_flush_wall
        store.append_samples(rows)
        rows.clear()
        last_flush_wall = time.perf_counter()
        if s is not None:
            store.set_progress(*_progress(s, last_flush_wall))

    def _progress(s: State, now: float):
        wall = now - start_wall
        rate = (s.step - start_step) / wall if wall > 0 else 0.0
        return solver.time(s), case.run.t_end, wall_before + wall, rate

    def checkpoint(s: State):
        nonlocal last_checkpoint_wall
        write_rows(s)
        store.write_checkpoint(s, flush)
        last_checkpoint_wall = time.perf_counter()

    def finish(status, message, s):
        now = time.perf_counter()
        store.set_progress(*_progress(s, now))
        store.set_status(status, message)
        flush()
        if status == FINISHED:
            faults.point("finished")
        return Outcome(status, message, solver.time(s), s.step - start_step, now - start_wall)

    try:
        while True:
            n = state.step
            rates = solver.rates(state)
            row = diagnostics.sample(solver, state, rates) if clock.sample_due(state) else None
            verdict = diagnostics.health(solver, state, row, last_correction)
            if not verdict.ok:
                if row is not None:
                    rows.append(row)
                raise (UnderResolved if verdict.under_resolved else Diverged)(verdict.reason)
            # State n is sound. A checkpoint of it counts only what was recorded
            # *before* it, so a resumed run records state n again, once.
            now = time.perf_counter()
            done = clock.done(state)
            stop = stop_requested() or (max_steps is not None and n - start_step >= max_steps)
            if n > start_step and (stop or done or clock.checkpoint_due(state)
                                   or (wall_interval > 0 and now - last_checkpoint_wall >= wall_interval)):
                checkpoint(state)
            if stop and not done:
                return finish(INTERRUPTED, f"stopped at t = {solver.time(state):.6g}; resume to continue",
                              state)
            if row is not None:
                rows.append(row)
                theta_now = row["theta"]
            if clock.snapshot_due(state):
                store.append_snapshot(diagnostics.snapshot(solver, state, rates))
            if deciding and row is not None:
                for name in decision.SERIES:
                    history[name].append(row[name])
                if len(history["t"]) % case.run.decision_samples == 0:
                    decided = decision.decide({name: np.asarray(v) for name, v in history.items()},
                                              case.physics.shear_rate, case.run, analysis)
                    if decided is not None:
                        write_rows()
                        store.set_decision(decision.CODES[decided.regime], state.t, state.step)
                        return finish(FINISHED, decided.message(), state)
            if done:
                write_rows()
                return finish(FINISHED, "", state)
            if len(rows) >= SAMPLE_BUFFER_ROWS or now - last_flush_wall >= SAMPLE_FLUSH_SECONDS:
                write_rows(state)
                flush()
            if progress is not None and now - last_tick >= 0.5:
                last_tick = now
                rate = (n - start_step) / (now - start_wall) if now > start_wall else 0.0
                done_fraction = clock.fraction(state)
                pace = (done_fraction - start_fraction) / (now - start_wall) if now > start_wall else 0.0
                eta = (1.0 - done_fraction) / pace if pace > 0 else float("inf")
                progress(Tick(solver.time(state), case.run.t_end, rate, eta, theta_now))
            before = state.area_correction
            state, _ = clock.take_step(solver, state, rates)
            last_correction = state.area_correction - before
    except (Diverged, TensionSolveError, ArithmeticError, FloatingPointError) as exc:
        write_rows()
        reason = str(exc) if isinstance(exc, Diverged) else f"{type(exc).__name__}: {exc}"
        kept = ("last good checkpoint kept" if store.newest_checkpoint_slot() is not None
                else "no checkpoint had been written yet")
        what = "under-resolved" if isinstance(exc, UnderResolved) else "diverged"
        limit = "" if case.physics.homogeneous else beyond_model(state, case.physics.bending_law)
        if limit:
            return finish(MODEL_LIMIT, f"{MODEL_LIMIT_PREFIX}{limit}{STOPPED_BY}{what}: {reason} ({kept})", state)
        return finish(FAILED, f"{what}: {reason} ({kept})", state)
