"""When a run samples, snapshots, checkpoints and ends: pure functions of a case and a state.

Two clocks, one interface:

* :class:`FixedClock` -- a fixed step dt; everything happens at multiples of
  round(interval / dt) steps (the run ends at n_steps = round(t_end / dt)).
* :class:`AdaptiveClock` -- the step chosen by error control (stepcontrol.py);
  samples, snapshots and checkpoints at multiples j * interval of simulated
  time, and the end at t_end. Steps are cut so that they land on these times
  exactly (stepcontrol.fit_to): every sample is a state of the scheme, nothing
  is interpolated. Times of two cadences that agree to 1e-9 of an interval
  (0.1 and 10 * 0.01) are one event, and a state is on an event when its
  time is (a time within 1e-13 of its own size of a grid time: the round-off
  of landing there; the start-up's steps of 1e-9 at t ~ 0 are not on t = 0).

Both count what a run has recorded *before* a state, so a checkpoint of that
state says how many samples and snapshots a resumed run keeps.
"""
from __future__ import annotations

import math
from typing import Protocol

from hpcves.model.params import Case
from hpcves.numerics.stepcontrol import StepControl, advance, fixed

#: two event times closer than this fraction of an interval are the same event
COINCIDENT = 1e-9
#: How far x = t / interval may lie from a whole number j and still be j: ROUNDOFF intervals near
#: t = 0 (a step lands on an event to round-off, and steps far below 1e-9 of an interval are taken:
#: the spinodal start-up), RELATIVE of x beyond. Intervals are rounded to 12 significant digits
#: (study.TimeRules), so the grid times of two cadences that should coincide drift apart by up to
#: ~1e-12 of the time: 28 samples of 0.00357142857143 (1/280) end at 0.10000000000004, 4e-14 after
#: the 5th snapshot of 0.02 (as two events: a step of 4e-14, below the controller's floor, and the
#: case failed); 2520 of them end 3.6e-12 after the 450th, 1e-9 of a sample interval (a slack capped
#: there took them as two events, and each was on the snapshot grid: three snapshots at t = 9, and
#: the snapshots overflowed their capacity).
ROUNDOFF = 1e-13
RELATIVE = 1e-11


#: events() of a state on no grid
NONE_DUE = (False, False, False)


def _slack(x: float) -> float:
    """How far x = t / interval may lie from a whole number j and still be j (in intervals)."""
    return max(ROUNDOFF, RELATIVE * abs(x))


def _legacy_slack(x: float) -> float:
    """The slack of hpcves before the coincidence fix: a file it finished may hold one sample or
    snapshot fewer at t_end (CaseStore.problems accepts either count)."""
    return min(COINCIDENT, ROUNDOFF * max(abs(x), 1.0))


class Clock(Protocol):
    """What the run loop and the store ask of a clock (:class:`FixedClock`, :class:`AdaptiveClock`):
    the rows a run records and when, how far it is, and its next step."""

    def legacy(self) -> "Clock":
        """The clock of hpcves before the coincidence fix (a file it finished reads with it)."""

    def capacities(self) -> tuple[int, int]:
        """Rows to preallocate: (samples, snapshots)."""

    def recorded(self, step: int, t: float) -> tuple[int, int]:
        """(samples, snapshots) a run has recorded once it has taken ``step`` steps to ``t``."""

    def finished_counts(self) -> tuple[int, int]:
        """(samples, snapshots) of a run that reached its end."""

    def recorded_through(self, step: int, t: float) -> tuple[int, int]:
        """The rows recorded up to and including the state at (``step``, ``t``)."""

    def sample_due(self, state) -> bool: ...

    def snapshot_due(self, state) -> bool: ...

    def checkpoint_due(self, state) -> bool: ...

    def events(self, state) -> tuple[bool, bool, bool]:
        """(sample, snapshot, checkpoint) due at ``state``."""

    def done(self, state) -> bool: ...

    def fraction(self, state) -> float:
        """How far the run is, 0 to 1."""

    def take_step(self, solver, state, rates):
        """The next state (and its rates) from ``state``."""


class FixedClock:
    """Cadences in whole steps of numerics.dt."""

    def legacy(self) -> "FixedClock":
        """The same clock (whole steps have no coincidence rule to change)."""
        return self

    adaptive = False

    def __init__(self, case: Case):
        self.n_steps = case.n_steps
        self.sample_every = case.every(case.run.sample_interval)
        self.snapshot_every = case.every(case.run.snapshot_interval)
        self.checkpoint_every = case.every(case.run.checkpoint_interval)

    def capacities(self) -> tuple[int, int]:
        """Rows to preallocate for samples and snapshots (every multiple, plus the end)."""
        n = self.n_steps
        return n // self.sample_every + 2, n // self.snapshot_every + 2

    def recorded(self, step: int, t: float) -> tuple[int, int]:
        """(samples, snapshots) recorded before step ``step``."""
        def count(every):
            return 0 if step <= 0 else (step - 1) // every + 1
        return count(self.sample_every), count(self.snapshot_every)

    def finished_counts(self) -> tuple[int, int]:
        return self.recorded(self.n_steps + 1, math.inf)

    def recorded_through(self, step: int, t: float) -> tuple[int, int]:
        """(samples, snapshots) recorded up to and including the state after ``step`` steps."""
        return self.recorded(step + 1, t)

    def sample_due(self, state) -> bool:
        return state.step % self.sample_every == 0

    def snapshot_due(self, state) -> bool:
        return state.step % self.snapshot_every == 0

    def checkpoint_due(self, state) -> bool:
        return state.step % self.checkpoint_every == 0

    def events(self, state) -> tuple[bool, bool, bool]:
        """(sample_due, snapshot_due, checkpoint_due) of ``state``."""
        step = state.step
        return (step % self.sample_every == 0, step % self.snapshot_every == 0,
                step % self.checkpoint_every == 0)

    def done(self, state) -> bool:
        return state.step >= self.n_steps

    def fraction(self, state) -> float:
        return state.step / self.n_steps

    def take_step(self, solver, state, rates):
        """(new state, rejected steps)."""
        return solver.step(state, rates)[0], 0


class AdaptiveClock:
    """Cadences in simulated time; steps by error control, cut to land on every event."""

    adaptive = True

    def __init__(self, case: Case, slack=_slack):
        run, num = case.run, case.numerics
        self.t_end = run.t_end
        self.intervals = (run.sample_interval, run.snapshot_interval, run.checkpoint_interval)
        self.control = StepControl(rtol=num.rtol, atol=num.atol, dt_max=num.dt_max, initial_dt=num.dt_initial)
        self._slack = slack
        #: numerics.startup_dt and startup_time: fixed steps before the controller takes over (0, 0: none)
        self.startup = (num.startup_dt, num.startup_time)

    def legacy(self) -> "AdaptiveClock":
        """This clock with the coincidence rule of hpcves before the fix (for files it wrote)."""
        other = object.__new__(type(self))
        other.__dict__.update(self.__dict__, _slack=_legacy_slack)
        return other

    # -------------------------------------------------------------- the time grid
    def _on_grid(self, t: float, interval: float) -> bool:
        x = t / interval
        j = round(x)
        return abs(x - j) <= self._slack(x) and j * interval <= self.t_end * (1 + COINCIDENT)

    def _count_before(self, t: float, interval: float) -> int:
        """Grid times j * interval (up to t_end) before t: ceil(t / interval), coincident times excluded."""
        x = t / interval
        return min(self._last(interval), max(0, math.ceil(x - self._slack(x))))

    def _total(self, interval: float) -> int:
        """Grid times up to t_end by the rule the file's layout was made with (capacity - 1): the
        layout of files from before the coincidence fix must keep its shape."""
        return math.floor(self.t_end / interval + COINCIDENT) + 1

    def _last(self, interval: float) -> int:
        """Grid times up to t_end, t_end itself where it coincides with one (at most _total + 1)."""
        x = self.t_end / interval
        return math.floor(x + self._slack(x)) + 1

    def _next(self, t: float, interval: float) -> float:
        """The first multiple of ``interval`` after t (and not coincident with it)."""
        x = t / interval
        j = math.floor(x + self._slack(x)) + 1
        return j * interval

    def capacities(self) -> tuple[int, int]:
        sample, snapshot, _ = self.intervals
        return self._total(sample) + 1, self._total(snapshot) + 1

    def recorded(self, step: int, t: float) -> tuple[int, int]:
        """(samples, snapshots) recorded before time t."""
        sample, snapshot, _ = self.intervals
        if step <= 0:
            return 0, 0
        return self._count_before(t, sample), self._count_before(t, snapshot)

    def finished_counts(self) -> tuple[int, int]:
        sample, snapshot, _ = self.intervals
        return self._last(sample), self._last(snapshot)

    def recorded_through(self, step: int, t: float) -> tuple[int, int]:
        """(samples, snapshots) recorded up to and including the state at time t."""
        sample, snapshot, _ = self.intervals
        return tuple(min(self._last(i), math.floor(t / i + self._slack(t / i)) + 1) for i in (sample, snapshot))

    # -------------------------------------------------------------- cadences
    def _due(self, state, interval: float) -> bool:
        """Whether ``state`` is on the grid of ``interval`` and the state before it was not on the same
        grid time: after a landing the controller can take a step far below the slack (1.6e-10 after
        t = 23.26 in a case at N = 256), and both states would be that grid time's (a sample twice)."""
        if not self._on_grid(state.t, interval):
            return False
        if state.step <= 0 or not math.isfinite(state.dt_prev):
            return True
        before = state.t - state.dt_prev
        return not (self._on_grid(before, interval) and round(before / interval) == round(state.t / interval))

    def sample_due(self, state) -> bool:
        return self._due(state, self.intervals[0])

    def snapshot_due(self, state) -> bool:
        return self._due(state, self.intervals[1])

    def checkpoint_due(self, state) -> bool:
        return self._due(state, self.intervals[2])

    def events(self, state) -> tuple[bool, bool, bool]:
        """(sample_due, snapshot_due, checkpoint_due) of ``state``, in one call a step: a time farther
        than either rule's slack (at most 1e-9 + 1e-11 x) from every multiple of an interval (most
        states) is on none of the grids."""
        t = state.t
        a, b, c = self.intervals
        x, y, z = t / a, t / b, t / c
        near_a = abs(x - round(x)) <= 1e-9 + 1e-11 * abs(x)
        near_b = abs(y - round(y)) <= 1e-9 + 1e-11 * abs(y)
        near_c = abs(z - round(z)) <= 1e-9 + 1e-11 * abs(z)
        if not (near_a or near_b or near_c):
            return NONE_DUE
        return (near_a and self._due(state, a), near_b and self._due(state, b), near_c and self._due(state, c))

    def done(self, state) -> bool:
        return state.t >= self.t_end * (1 - COINCIDENT)

    def fraction(self, state) -> float:
        return state.t / self.t_end

    def next_event(self, t: float) -> float:
        return min(min(self._next(t, interval) for interval in self.intervals), self.t_end)

    def take_step(self, solver, state, rates):
        """(new state, rejected steps): one accepted step, landing on the next event if it reaches it --
        a fixed one of numerics.startup_dt while t is before numerics.startup_time (landing on it too)."""
        dt, until = self.startup
        if state.t < until * (1 - COINCIDENT):
            taken = fixed(solver, state, rates, dt, self.control, min(self.next_event(state.t), until))
            return taken.state, 0
        k = self.control.initial_dt if math.isnan(state.dt_next) else state.dt_next
        taken = advance(solver, state, rates, k, self.control, self.next_event(state.t))
        return taken.state, taken.rejections


def clock(case: Case) -> Clock:
    return AdaptiveClock(case) if case.numerics.adaptive else FixedClock(case)
