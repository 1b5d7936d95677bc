"""What a time step of a case costs on this machine, measured through the real run loop.

``hpcves campaign --plan`` multiplies these by the steps a case is expected to take
(campaign/plan.py). A step's cost depends on N, on whether the vesicle has a phase
field, and on how often it samples and snapshots; not on the shear rate or the step size
as such: each N is timed once (:class:`StepCost`), its samples and snapshots apart.
"""
from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path

from hpcves.model.params import Case, dealias_label
from hpcves.run.resolution import expected_N


def seconds_per_step(case: Case, steps: int = 150, repeats: int = 2, stop_requested=lambda: False) -> float:
    """Wall seconds a step of ``case`` takes here: the fewest over ``repeats`` fresh runs of
    ``steps`` steps into scratch files (each run's wall leaves out its set-up; the fewest, as
    a shared machine only ever adds time). Samples and snapshots are written as in a campaign.

    The runs take fixed steps of the size the case is expected to settle at
    (``Case.settled_step``): an adaptive run's first steps are tiny, so they sample far
    less often than the long stretch at the settled step that makes up a run. A run that
    stops early is timed over what it ran; its t_end is cut to just past the timed steps, so its file
    holds only what they write. Call it once first on a throw-away case if
    nothing ran in this process yet (:class:`StepCost` does): the first run pays for
    loading libraries and planning FFTs. ``stop_requested`` is polled every step (runner.run): once it
    is True the runs stop at once and what they measured means nothing (the caller is stopping)."""
    from hpcves.run.casefile import create_case_file, run_file

    numerics = dataclasses.replace(case.numerics, dt=case.settled_step, rtol=None)
    # the run ends just after the timed steps, so its file holds what they write, not the whole case's
    # samples and snapshots (which need not fit a scratch directory here: a cluster's study)
    t_end = min(case.run.t_end, (steps + 2) * numerics.dt)
    case = dataclasses.replace(case, numerics=numerics, run=dataclasses.replace(case.run, until_decided=False,
                                                                                t_end=t_end))
    best = float("inf")
    with tempfile.TemporaryDirectory(prefix="hpcves-timing-") as scratch:
        for i in range(repeats):
            outcome = run_file(create_case_file(Path(scratch) / f"t{i}.h5", case), resume=False, max_steps=steps,
                               stop_requested=stop_requested)
            best = min(best, outcome.wall / max(outcome.steps, 1))
    return best


#: what a campaign rank holds in memory (bench/bench_memory.py, BENCHMARKS.md "Memory of a rank"): the
#: peak resident set of a process that runs one case is RANK_BYTES, plus COMPILE_BYTES where it compiles
#: the engine (numba's cache not there yet: a cluster's first job), plus BYTES_PER_N2 N^2 for the dense
#: operators at N nodes (CONTRAST_BYTES_PER_N2 with a viscosity contrast: the double layer and GMRES);
#: the slopes from N = 2048, which lie above those of N <= 1024: the model errs on the large side there
RANK_BYTES = 222 * 2**20
COMPILE_BYTES = 232 * 2**20
BYTES_PER_N2 = 90
CONTRAST_BYTES_PER_N2 = 122


def rank_bytes(N: int, contrast: bool, compiling: bool = True) -> int:
    """The peak memory of a rank whose cases reach N nodes (rates on N: de-aliased, the larger grid)."""
    return RANK_BYTES + (COMPILE_BYTES if compiling else 0) + (CONTRAST_BYTES_PER_N2 if contrast
                                                               else BYTES_PER_N2) * N * N


@dataclasses.dataclass(frozen=True)
class StepParts:
    """A step's wall seconds taken apart: the step itself (the solve and the loop around it), and what a
    sample and a snapshot add when one is due."""

    step: float
    sample: float
    snapshot: float

    def cost(self, samples: float, snapshots: float) -> float:
        """Seconds per step for shares ``samples`` and ``snapshots`` of the steps that sample and snapshot."""
        return self.step + samples * self.sample + snapshots * self.snapshot


class StepCost:
    """A step's cost, timed once per N and remembered: ``cost(case)`` for every case of a study,
    ``measured`` for a report.

    A step's cost is the solve (N; with or without a phase field; the rates' grid) plus what it
    writes: a sample of every series costs about as much as the solve, a snapshot more (h5py's
    per-dataset overhead; docs/numerics.md). The shares of steps that sample and snapshot differ
    from case to case (the step, the sampling and t_end scale differently with S), so each kind of
    solve is timed three ways -- writing nothing, sampling every step, snapshotting every step --
    and a case's cost is ``StepParts.cost`` at its own shares."""

    def __init__(self, steps: int = 150, announce=lambda text: None, stop_requested=lambda: False):
        self.steps, self.announce, self.stop_requested = steps, announce, stop_requested
        self.measured: dict = {}             # kind (kind_of) -> StepParts

    @staticmethod
    def kind_of(case: Case) -> tuple:
        """(N, homogeneous, dealias): what sets the solve's cost; where N adapts, the N its start needs
        (resolution.expected_N: the run is timed from that start)."""
        return expected_N(case), case.physics.homogeneous, case.numerics.dealias

    @staticmethod
    def shares(case: Case) -> tuple[float, float]:
        """The shares of a case's steps that sample and snapshot, at its settled step."""
        dt = case.settled_step
        return min(1.0, dt / case.run.sample_interval), min(1.0, dt / case.run.snapshot_interval)

    def __call__(self, case: Case) -> float:
        kind = self.kind_of(case)
        if kind not in self.measured:
            N, homogeneous, dealias = kind
            self.announce(f"timing a step at N = {N}" + (" (homogeneous)" if homogeneous else "")
                          + dealias_label(dealias) + ", with and without samples and snapshots ...")
            if not self.measured:              # the first run in a process loads and plans: not timed
                seconds_per_step(case, steps=20, repeats=1, stop_requested=self.stop_requested)
            self.measured[kind] = self._parts(case)
        return self.measured[kind].cost(*self.shares(case))

    def _parts(self, case: Case) -> StepParts:
        """The three timings of ``case``'s kind of step; a write's share is the difference to the bare
        step (never below 0: on a busy machine the bare step may come out the slower)."""
        dt = case.settled_step                             # fixed, whatever the sampling below
        case = dataclasses.replace(case, numerics=dataclasses.replace(case.numerics, dt=dt, rtol=None))
        far = 1e6 * max(dt, case.run.t_end)                # an interval no timed run reaches

        def timed(sample: float, snapshot: float) -> float:
            run = dataclasses.replace(case.run, sample_interval=sample, snapshot_interval=snapshot)
            return seconds_per_step(dataclasses.replace(case, run=run), self.steps,
                                    stop_requested=self.stop_requested)

        bare = timed(far, far)
        return StepParts(bare, max(0.0, timed(dt, far) - bare), max(0.0, timed(far, dt) - bare))


#: the samples of the case whose layout is timed (layout_seconds)
LAYOUT_ROWS = 100
#: the longest synthetic record whose classification is timed (classify_seconds)
CLASSIFY_ROWS = 200_000


def layout_seconds(case: Case, count: int = 256) -> float:
    """Wall seconds rank 0 takes to lay out one more case like ``case`` in a campaign file: a block
    (blocks.py) grown by ``count`` such cases at once, measured here in memory, divided by ``count``,
    for a case of its N with at most LAYOUT_ROWS samples (its chunks, not its bytes: a case of 5 GB
    would not fit in memory); writing the preallocated bytes to disk comes on top."""
    import dataclasses
    import time

    import h5py

    from hpcves.run.blocks import Blocks
    from hpcves.run.store import OBJECT_FORMAT

    run = case.run
    t_end = min(run.t_end, LAYOUT_ROWS * max(run.sample_interval, case.numerics.dt or 0.0))
    if t_end < run.t_end:
        case = dataclasses.replace(case, run=dataclasses.replace(run, t_end=t_end))
    with h5py.File("layout.h5", "w", driver="core", backing_store=False, libver=OBJECT_FORMAT) as h5:
        blocks = Blocks.create(h5)
        blocks.add([case])
        start = time.perf_counter()
        blocks.add([case] * count)
        return (time.perf_counter() - start) / count


def classify_seconds(case: Case, repeats: int = 3) -> float:
    """Wall seconds the classification of one ended case like ``case`` takes here (regimes.classify on
    a synthetic record as long as the case's sample capacity; reading it from the file comes on top).
    A record longer than CLASSIFY_ROWS is timed at that length and scaled by n log n (the FFTs of the
    autocorrelation): a capacity of 1e8 samples took 20 GB to time whole."""
    import math
    import time

    import numpy as np

    from hpcves.analysis.regimes import AnalysisSettings, classify
    from hpcves.run.store import capacities

    capacity = max(capacities(case)[0], 2)
    n = min(capacity, CLASSIFY_ROWS)
    scale = capacity * math.log(capacity) / (n * math.log(n))
    t = np.linspace(0.0, case.run.t_end, n)
    rng = np.random.default_rng(0)
    series = {"t": t, "theta": 0.3 + 0.05 * np.sin(2 * np.pi * t * max(case.physics.shear_rate, 1.0) / 20)
              + 1e-6 * rng.standard_normal(n),
              "V_psi": np.full(n, 0.1), "V_L": np.full(n, -0.1), "tank_treading_velocity": np.full(n, -1.0),
              "psi_min": np.zeros(n), "psi_max": np.ones(n), "E_bending": 10.0 + 0.01 * np.sin(t)}
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        classify(series, AnalysisSettings())
        best = min(best, time.perf_counter() - start)
    return best * scale
