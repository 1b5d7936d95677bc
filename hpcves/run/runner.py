"""Drive one case: step, sample, snapshot, checkpoint, stop cleanly.

The loop is short: take the state's rates, its sample when one is due, check
its health; then hand the state to a list of **cadences** in order -- each a
small object with ``due(moment)`` and a call that may end the run (as Dedalus's
evaluator runs its handlers): Checkpoints, Interruption, Samples, Snapshots,
Decisions (run.until_decided), End, SampleFlush, Ticks (the progress display);
then step. Most states are on no cadence's grid: the clock says so in one call
(``events``) and, with no stop asked for and no cadence's wall timer up
(``wake``), the cadences are not asked.

Everything here is deterministic in the state -- samples, snapshots and
checkpoints when the clock (schedule.py: whole steps for a fixed dt, simulated
time for an adaptive one) says so, plus extra checkpoints on a wall-clock timer
and on request, which read the state but never change it; the step controller's
memory is part of the state -- so a run resumed from any checkpoint reproduces
the uninterrupted one bit for bit.
"""
from __future__ import annotations

import abc
import dataclasses
import logging
import math
import time
from dataclasses import dataclass
from typing import Callable, NamedTuple

import numpy as np
from threadpoolctl import threadpool_limits

from hpcves.analysis.regimes import AnalysisSettings
from hpcves.files import faults
from hpcves.model.flow import TensionSolveError
from hpcves.run import decision, diagnostics, resolution, schedule
from hpcves.run import store as checkpoint_module
from hpcves.run.store import FAILED, FINISHED, INTERRUPTED, MODEL_LIMIT, RUNNING, CaseRecord, Status
from hpcves.run.stored import read_stored_start
from hpcves.solver.timestepping import Solver, State

log = logging.getLogger(__name__)

#: psi beyond [-OVERSHOOT, 1 + OVERSHOOT] when a run under the linear bending law gives out: the
#: model's limit, not a failure (healthy steps stay within 0.005 of [0, 1]; beyond_model)
OVERSHOOT = 0.03

#: write buffered samples at least this often (seconds), so that a running case can be watched
SAMPLE_FLUSH_SECONDS = 10.0
SAMPLE_BUFFER_ROWS = 512
SNAPSHOT_BUFFER = 64           # snapshots held before they are written (64 x 7 fields x N doubles)


@dataclass(frozen=True)
class Outcome:
    status: Status       # FINISHED / FAILED / MODEL_LIMIT / INTERRUPTED
    message: str
    t: float
    steps: int           # steps taken in this call
    wall: float          # seconds spent in this call
    end: tuple | None = None   # FINISHED: (theta_tilde, psi) of the state it ended in (kept as its checkpoint)


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


class Stalled(Diverged):
    """The adaptive step collapsed (run.max_steps_per_shear_time): see :func:`stalled`."""


#: how a stalled run's reason begins
STALLED = "stalled"


#: the shortest sample interval the stall watch counts, in shear times: the spinodal start-up takes
#: its steps whatever S is (4112 steps before t = 0.02 at S = 1, psi_bar = 0.41, Delta = 0.94) ...
STALL_MIN_INTERVAL = 0.1
#: ... at rtol = 1e-3 or looser; below it the error control resolves the start-up with about 1 / rtol more
#: steps (Delta = 0.94, psi_bar = 0.5625, S = 2 before t = 0.02: 3489 at 1e-3, 25059 at 1e-4 from the
#: authors' start; 2538 and 16858 from the ellipse; docs/numerics.md, "Stalled runs"), and so does the floor
STALL_RTOL = 1e-3


def stall_allowance(case) -> float:
    """The steps a run may take from one sample to the next: run.max_steps_per_shear_time for a whole
    sample interval, t and steps in shear times (time units below S = 1), the interval counted as at
    least STALL_MIN_INTERVAL x max(1, STALL_RTOL / rtol); inf for a fixed step (it cannot collapse)
    or no limit."""
    limit = case.run.max_steps_per_shear_time
    if not limit or not case.numerics.adaptive:
        return math.inf
    S = max(case.physics.shear_rate, 1.0)
    floor = STALL_MIN_INTERVAL * max(1.0, STALL_RTOL / case.numerics.rtol)
    return limit * max(case.run.sample_interval * S, floor)


def stalled(case, state: State, since: tuple[float, int]) -> str:
    """Why the run stalls ("" while it does not): more steps since the sample ``since`` = (t, step)
    than :func:`stall_allowance` allows."""
    taken = state.step - since[1]
    if taken <= stall_allowance(case):
        return ""
    limit = case.run.max_steps_per_shear_time
    S = max(case.physics.shear_rate, 1.0)
    return (f"the time step collapsed: {taken} steps from the sample at t = {since[0]:.6g} to t = {state.t:.6g} "
            f"({(state.t - since[0]) * S:.3g} shear times), more than run.max_steps_per_shear_time = {limit:g} "
            f"allows for a sample interval; the last step {state.dt_prev:.2g} at N = {state.N} (where measured, "
            "the modes near N/2 had grown while the others decayed: docs/numerics.md, \"Stalled runs\")")


#: how a model-limit stop's message begins, and what follows its cause (model_limit_cause)
MODEL_LIMIT_PREFIX, STOPPED_BY = "model limit: ", "; the run stopped "
#: how a failed case's message begins when N did not resolve it (a larger N may)
UNDER_RESOLVED = "under-resolved"


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


def run(store: CaseRecord, flush: Callable[[], None], *, resume: bool = False,
        progress: Callable[[Tick], None] | None = None,
        stop_requested: Callable[[], bool] = lambda: False,
        max_steps: int | None = None, analysis: AnalysisSettings = AnalysisSettings(),
        start: tuple | None = None) -> Outcome:
    """Run (or continue) the case in ``store`` to its end time (or, with run.until_decided, until
    decided by the classification with the thresholds ``analysis``: decision.py).

    ``flush`` makes the file durable (h5py File.flush). ``stop_requested`` is
    polled every step; when it returns True the current state is checkpointed
    and the run returns as INTERRUPTED. ``max_steps`` stops after that many
    steps in this call, the same way (for tests and for time-sliced work).
    ``start``: (theta_tilde, psi) of another state the case starts from (a chain's case: the end
    of the one before; Solver), given again on every resume.
    BLAS and OpenMP run on one thread meanwhile (:func:`one_thread`).
    """
    with one_thread():
        return _run(store, flush, resume, progress, stop_requested, max_steps, analysis, start)


def _run(store, flush, resume, progress, stop_requested, max_steps, analysis, start) -> Outcome:
    case = store.case
    if start is None and case.physics.initial_shape == "stored":
        start = read_stored_start(case.physics)
    solver = resolution.starting_solver(case, start) if case.numerics.adaptive_N else Solver(case, start=start)
    state = None
    wall_before = 0.0                  # wall time of earlier calls on this case
    note = ""                          # a checkpoint passed over because it fails its checksums
    resumed = False                    # from a checkpoint: the samples before it are on file
    if resume:
        wall_before = float(np.nan_to_num(store.progress[2]))
        found = store.read_checkpoint()
        if found is not None:
            if note := store.passed_over():
                log.warning(note)
            state, n_samples, n_snapshots = found
            resumed = True
            store.truncate(n_samples, n_snapshots)
            solver = solver.at(state.N)
    if state is None:
        state = solver.initial_state()
        store.truncate(0, 0)
    clock = schedule.clock(case)
    last_sample = _last_sample(store, state) if resumed else (state.t, state.step)   # the stall watch
    record = _Record(store, flush, solver, state.step, wall_before)
    samples = Samples(record)
    decisions = Decisions(record, analysis) if case.run.until_decided else None
    cadences = [Checkpoints(record, case.run.checkpoint_wall, decisions), Interruption(record), samples,
                Snapshots(record)]
    if decisions is not None:
        cadences.append(decisions)
    store.set_decision(*checkpoint_module.NOT_DECIDED)
    cadences += [End(record), SampleFlush(record)]
    if progress is not None:
        cadences.append(Ticks(record, clock, progress, state, samples))
    store.set_status(RUNNING, note, "")
    flush()
    timers = [cadence for cadence in cadences if type(cadence).wake is not Cadence.wake]
    last_correction = 0.0          # relative area correction made by the last step
    wake = -math.inf               # the wall time at which a cadence's timer may next be due
    allowance = stall_allowance(case)
    try:
        while True:
            try:
                rates = solver.rates(state)
            except TensionSolveError as exc:   # the shape outgrew the grid: one size up, where N adapts
                if not case.numerics.adaptive_N:
                    raise
                larger = resolution.larger_N(case, state.N)
                if larger is None:
                    raise UnderResolved(f"the tension solve finds the shape unresolved at t = {state.t:.6g} on "
                                        f"N = {state.N} (numerics.N_max: N grew as far as it may): {exc}") from None
                solver, state = solver.resized(state, larger)
                record.solver = solver
                continue
            sample_due, snapshot_due, checkpoint_due = clock.events(state)
            row = diagnostics.sample(solver, state, rates) if sample_due else None
            if row is not None and case.numerics.adaptive_N:
                solver, state, rates, row = _resolve(solver, state, rates, row)
                record.solver = solver
            if row is not None:
                last_sample = (state.t, state.step)
            verdict = diagnostics.health(solver, state, row, last_correction)
            if not verdict.ok:
                if row is not None:
                    record.rows.append(row)
                raise (UnderResolved if verdict.under_resolved else Diverged)(verdict.reason)
            # State n is sound: the cadences act on it, in order, until one ends the run -- unless
            # nothing is due: no sample, snapshot, checkpoint, end or stop, and no cadence's wall timer.
            wall, done = time.perf_counter(), clock.done(state)
            stop = stop_requested() or (max_steps is not None and state.step - record.start_step >= max_steps)
            if row is not None or snapshot_due or checkpoint_due or done or stop or wall >= wake:
                moment = Moment(state, rates, row, wall, done, stop, snapshot_due, checkpoint_due)
                for cadence in cadences:
                    if cadence.due(moment) and (ended := cadence(moment)) is not None:
                        return ended
                wake = min(cadence.wake() for cadence in timers)
            if state.step - last_sample[1] > allowance:
                raise Stalled(stalled(case, state, last_sample))
            before = state.area_correction
            state, _ = clock.take_step(solver, state, rates)
            last_correction = state.area_correction - before
    except (Diverged, TensionSolveError, ArithmeticError, FloatingPointError) as exc:
        record.write_rows()
        reason = str(exc) if isinstance(exc, Diverged) else f"{type(exc).__name__}: {exc}"
        kept = ("last good checkpoint kept" if store.newest_checkpoint_slot() is not None
                else "no checkpoint had been written yet")
        what = (UNDER_RESOLVED if isinstance(exc, UnderResolved) else STALLED if isinstance(exc, Stalled)
                else "diverged")
        limit = "" if case.physics.homogeneous else beyond_model(state, case.physics.bending_law)
        if limit:
            return record.finish(MODEL_LIMIT, f"{MODEL_LIMIT_PREFIX}{limit}{STOPPED_BY}{what}: {reason} ({kept})",
                                 state)
        return record.finish(FAILED, f"{what}: {reason} ({kept})", state)


def _last_sample(store: CaseRecord, state: State) -> tuple[float, int]:
    """(t, step) of the last sample a run resumed at ``state`` keeps (the state's own where there is none
    yet, or the file predates the step series). ``store`` may be a relay's RemoteCaseStore: only its
    CaseStore interface is used."""
    series = store.timeseries()
    if len(series.get("step", ())):
        return float(series["t"][-1]), int(series["step"][-1])
    return state.t, state.step


def _resolve(solver: Solver, state: State, rates, row: dict):
    """N adapting (resolution.py), at a sample: (solver, state, rates, row) on the N it goes on with,
    the state and its sample taken again after a resize (and again while it still asks to grow)."""
    while True:
        theta_hat = solver.sp.fft.rfft(state.theta)
        N, quiet_since = resolution.decide(solver.case, theta_hat, rates.psi_hat, state.N, state.quiet_since,
                                           state.t)
        if N == state.N:
            unchanged = quiet_since == state.quiet_since or (math.isnan(quiet_since) and math.isnan(state.quiet_since))
            return solver, state if unchanged else dataclasses.replace(state, quiet_since=quiet_since), rates, row
        solver, state = solver.resized(state, N)            # (decide gives NaN after a resize; so does resized)
        rates = solver.rates(state)
        row = diagnostics.sample(solver, state, rates)


# ---------------------------------------------------------------------- the cadences
class Moment(NamedTuple):
    """What the cadences read about state n, once it is known to be sound (a NamedTuple: made at
    every sample, where a frozen dataclass's __init__ cost ~1.5 us)."""

    state: State
    rates: object              # the solver's rates at the state (its snapshot reads them)
    row: dict | None           # the state's sample, when one is due
    wall: float                # time.perf_counter() then
    done: bool                 # the end time is reached
    stop: bool                 # a stop was asked for (a signal, or max_steps in this call)
    snapshot: bool = False     # the state is on the clock's snapshot grid
    checkpoint: bool = False   # ... on its checkpoint grid


class Cadence(abc.ABC):
    """What the run loop asks of a cadence: ``due(moment)``, a call that may end the run (an Outcome)
    or not (None), and ``wake()``: the wall time (time.perf_counter) before which it cannot be due at
    a moment without a sample, snapshot, checkpoint, end or stop (the loop skips such moments)."""

    @abc.abstractmethod
    def due(self, m: Moment) -> bool: ...

    @abc.abstractmethod
    def __call__(self, m: Moment) -> "Outcome | None": ...

    def wake(self) -> float:
        return math.inf


class _Record:
    """What one call of run writes besides the checkpoints: buffered samples and snapshots, the
    progress numbers (t, t_end, wall, steps per second), the final status. Samples and snapshots
    are written in blocks (a write of one row costs about as much as one of hundreds), always
    before a checkpoint, which counts them."""

    def __init__(self, store: CaseRecord, flush: Callable[[], None], solver: Solver, start_step: int,
                 wall_before: float):
        self.store, self.flush, self.solver = store, flush, solver
        self.start_step, self.wall_before = start_step, wall_before
        self.rows: list[dict] = []
        self.snapshots: list[dict] = []
        self.start_wall = self.last_flush_wall = time.perf_counter()

    def write_rows(self, state: State | None = None):
        """Write the buffered samples and snapshots (and, given the current state, the progress)."""
        self.store.append_samples(self.rows)
        self.rows.clear()
        self.store.append_snapshots(self.snapshots)
        self.snapshots.clear()
        self.last_flush_wall = time.perf_counter()
        if state is not None:
            self.store.set_progress(*self.progress(state, self.last_flush_wall))

    def progress(self, state: State, now: float) -> tuple:
        wall = now - self.start_wall
        rate = (state.step - self.start_step) / wall if wall > 0 else 0.0
        return self.solver.time(state), self.solver.case.run.t_end, self.wall_before + wall, rate

    def finish(self, status: int, message: str, state: State) -> Outcome:
        now = time.perf_counter()
        self.store.set_progress(*self.progress(state, now))
        self.store.set_status(status, message)
        self.flush()
        end = None
        if status == FINISHED:
            faults.point("finished")
            end = (state.theta, state.psi)
        return Outcome(status, message, self.solver.time(state), state.step - self.start_step,
                       now - self.start_wall, end)


class Checkpoints(Cadence):
    """State n written whole on the clock's checkpoint grid, every run.checkpoint_wall seconds, at a
    stop and at the end (the end time, or the state a run is decided at: a chain's next case starts
    from it) -- never the state a call starts from (it is on file). A checkpoint of state n counts only
    what was recorded *before* it, so a run resumed from it records state n again, once."""

    def __init__(self, record: _Record, wall_interval: float, decisions: "Decisions | None" = None):
        self.record, self.wall_interval = record, wall_interval
        self.decisions = decisions
        self.last_wall = record.start_wall

    def due(self, m: Moment) -> bool:
        return m.state.step > self.record.start_step and (
            m.stop or m.done or m.checkpoint
            or (self.wall_interval > 0 and m.wall - self.last_wall >= self.wall_interval)
            or (self.decisions is not None and self.decisions.decided(m) is not None))

    def wake(self) -> float:
        return self.last_wall + self.wall_interval if self.wall_interval > 0 else math.inf

    def __call__(self, m: Moment):
        self.record.write_rows(m.state)
        self.record.store.write_checkpoint(m.state, self.record.flush)
        self.last_wall = time.perf_counter()


class Interruption(Cadence):
    """A stop before the end: INTERRUPTED, to be resumed (Checkpoints has just written the state)."""

    def __init__(self, record: _Record):
        self.record = record

    def due(self, m: Moment) -> bool:
        return m.stop and not m.done

    def __call__(self, m: Moment) -> Outcome:
        t = self.record.solver.time(m.state)
        return self.record.finish(INTERRUPTED, f"stopped at t = {t:.6g}; resume to continue", m.state)


class Samples(Cadence):
    """The state's sample into the buffer (SampleFlush writes it out)."""

    def __init__(self, record: _Record):
        self.record = record
        self.theta = np.nan          # the latest sample's theta, for the progress line

    def due(self, m: Moment) -> bool:
        return m.row is not None

    def __call__(self, m: Moment):
        self.record.rows.append(m.row)
        self.theta = m.row["theta"]


class Snapshots(Cadence):
    """The state's fields on the clock's snapshot grid, into the buffer (SampleFlush writes it out)."""

    def __init__(self, record: _Record):
        self.record = record

    def due(self, m: Moment) -> bool:
        return m.snapshot

    def __call__(self, m: Moment):
        self.record.snapshots.append(diagnostics.snapshot(self.record.solver, m.state, m.rates))


class Decisions(Cadence):
    """run.until_decided: every run.decision_samples samples, classify the whole record so far
    (decision.py, thresholds ``analysis``) and end the run FINISHED once it is decided. It reads
    every sample from the start, on file or new: the same numbers after a resume."""

    def __init__(self, record: _Record, analysis: AnalysisSettings):
        self.record, self.analysis = record, analysis
        self.case = record.solver.case     # not store.case: that parses the stored TOML (~10 ms a call)
        recorded = record.store.timeseries()
        self.history = _History({name: recorded[name] for name in decision.SERIES})
        self._step, self._decided = None, None

    def decided(self, m: Moment):
        """The decision at state n (None: not decided); its sample joins the history once, whoever asks
        first (Checkpoints asks, to keep the state a run ends in)."""
        if m.row is None:
            return None
        if self._step != m.state.step:
            self._step = m.state.step
            self.history.append(m.row)
            case = self.case
            self._decided = None if len(self.history) % case.run.decision_samples else decision.decide(
                self.history.values(), case.physics.shear_rate, case.run, self.analysis)
        return self._decided

    def due(self, m: Moment) -> bool:
        return self.decided(m) is not None

    def __call__(self, m: Moment) -> Outcome | None:
        decided = self.decided(m)
        self.record.write_rows()
        self.record.store.set_decision(decision.CODES[decided.regime], m.state.t, m.state.step)
        return self.record.finish(FINISHED, decided.message(), m.state)


class _History:
    """Series that grow by a sample at a time, read as arrays of the values so far: one row of a
    (series, capacity) array each, doubled when full (lists turned into arrays at every decision cost
    0.1-0.7 ms at 500-5000 samples)."""

    def __init__(self, recorded: dict):
        self.names = tuple(recorded)
        size = len(recorded[self.names[0]]) if self.names else 0
        self._data = np.empty((len(self.names), max(2 * size, 1024)))
        for row, name in zip(self._data, self.names):
            row[:size] = recorded[name]
        self._size = size
        self._rows = list(zip(self.names, self._data))

    def __len__(self) -> int:
        return self._size

    def append(self, sample: dict) -> None:
        """Add a sample's values (a row of diagnostics.sample)."""
        n = self._size
        if n == self._data.shape[1]:
            self._data = np.concatenate([self._data, np.empty_like(self._data)], axis=1)
            self._rows = list(zip(self.names, self._data))
        for name, row in self._rows:
            row[n] = sample[name]
        self._size = n + 1

    def values(self) -> dict:
        """{name: the values so far} (read-only views: later appends write beyond them, never into them)."""
        out = {}
        for name, row in self._rows:
            view = row[:self._size]
            view.flags.writeable = False
            out[name] = view
        return out


class End(Cadence):
    """The end time: the last samples out, FINISHED."""

    def __init__(self, record: _Record):
        self.record = record

    def due(self, m: Moment) -> bool:
        return m.done

    def __call__(self, m: Moment) -> Outcome:
        self.record.write_rows()
        return self.record.finish(FINISHED, "", m.state)


class SampleFlush(Cadence):
    """The buffered samples, snapshots and the progress to the file when SAMPLE_BUFFER_ROWS samples
    or SNAPSHOT_BUFFER snapshots have gathered or SAMPLE_FLUSH_SECONDS have passed, so that a
    running case can be watched."""

    def __init__(self, record: _Record):
        self.record = record

    def due(self, m: Moment) -> bool:
        return (len(self.record.rows) >= SAMPLE_BUFFER_ROWS or len(self.record.snapshots) >= SNAPSHOT_BUFFER
                or m.wall - self.record.last_flush_wall >= SAMPLE_FLUSH_SECONDS)

    def wake(self) -> float:
        return self.record.last_flush_wall + SAMPLE_FLUSH_SECONDS

    def __call__(self, m: Moment):
        self.record.write_rows(m.state)
        self.record.flush()


class Ticks(Cadence):
    """A Tick for the progress display every half second of wall time."""

    def __init__(self, record: _Record, clock, progress: Callable[[Tick], None], start: State, samples: Samples):
        self.record, self.clock, self.progress, self.samples = record, clock, progress, samples
        self.last = record.start_wall
        self.start_fraction = clock.fraction(start)

    def due(self, m: Moment) -> bool:
        return m.wall - self.last >= 0.5

    def wake(self) -> float:
        return self.last + 0.5

    def __call__(self, m: Moment):
        self.last = m.wall
        t, t_end, _, rate = self.record.progress(m.state, m.wall)
        elapsed = m.wall - self.record.start_wall
        fraction = self.clock.fraction(m.state)
        pace = (fraction - self.start_fraction) / elapsed if elapsed > 0 else 0.0
        eta = (1.0 - fraction) / pace if pace > 0 else float("inf")
        self.progress(Tick(t, t_end, rate, eta, self.samples.theta))
