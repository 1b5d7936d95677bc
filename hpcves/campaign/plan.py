"""What a study will cost before it runs: cases, core-hours, ranks and wall time (``--plan``).

A case is expected to take ``Case.estimated_steps`` steps (t_end over the step the
sampling, dt_max and the shear rate allow: model/params.py), each of the seconds
measured for its N on this machine (run/timing.py). A run with ``until_decided``
usually stops long before t_end, so for it the figure is a ceiling. Search and
refine studies gain their cases stage by stage: the first stage is known, the
rest is bounded by the budget -- a search converges within
``SearchSettings.cases_needed()`` cases (at most ``max_cases``), a refinement
spends at most ``max_cases`` -- and those later cases are priced at the mean of
the known ones (a search's at the shear rates it may visit). For ``until_decided``
the plan also gives the likely cost, each case ended when cases typically are
decided (DECIDED_AFTER, measured).

The wall time on P ranks replays the scheduler (scheduler.py): rank 0 lays out the
cases alone first (and a staged study's later ones before their stage), then the ranks compute
(all of them on up to four; on more, rank 0 only schedules: queue.computing_ranks), cases go out
most expensive first to whichever rank is free -- in a staged study each rank classifies the case it
ran as it ends --, and a stage starts when the one before has ended. Laying out and classifying are
measured here on the first stage's median case (timing.py), so a study of many short cases is not
planned as one rank per case whose job the creation alone outlasts. The suggested P is the fewest ranks that finish
within 10 % of the wall time with a rank for every case of the widest stage whose
width is known (a refinement's later stages are as wide as the boundaries it
finds make them: only its coarse grid counts).
"""
from __future__ import annotations

import dataclasses
import heapq
import math
from dataclasses import dataclass
from typing import Callable

from hpcves.analysis.refine import coarse_points
from hpcves.analysis.search import start_rates
from hpcves.campaign.queue import computing_ranks, ranks_for
from hpcves.campaign.study import Study
from hpcves.run.resolution import expected_N
from hpcves.run.timing import rank_bytes

#: the plan's wall time is within this factor of the fastest possible one
NEAR_FASTEST = 1.10
#: a case that runs until decided ends, typically, after this many times ``decided_shear_times``
#: shear times: the median over 308 cases of seven studies that stopped early (docs/numerics.md,
#: "Planning a campaign"; 10 % to 90 % of them: 0.8 to 1.7)
DECIDED_AFTER = 1.13


@dataclass(frozen=True)
class Stage:
    """``rounds`` stages alike: each of ``cases`` cases of the given seconds (known or typical)."""

    name: str
    seconds: tuple              # one entry per case of one such stage
    rounds: int = 1
    sized: bool = True          # its width is known (not a budget spread over the stages)

    @property
    def cases(self) -> int:
        return len(self.seconds) * self.rounds

    @property
    def core_seconds(self) -> float:
        return sum(self.seconds) * self.rounds


@dataclass(frozen=True)
class Plan:
    """A study's expected cost: the stages at most, what is known up front, and what N costs here."""

    study: str
    mode: str                   # grid, search, refine
    stages: tuple               # Stage, in order; the first is known, the others are bounds
    step_seconds: dict          # N -> (fewest, most) seconds per step over the study's cases, measured here
    units: int                  # searches or refinements (1 for a grid)
    likely: "Plan | None" = None   # until_decided: the same with each case ended when typically decided
    creation: float = 0.0       # seconds rank 0 takes to lay out the cases (the file, then each stage's)
    analysis: float = 0.0       # seconds `hpcves analyze` takes afterwards to classify every case (not in the job)

    @property
    def ceiling(self) -> bool:
        """Whether the stages are ceilings that cases usually stay below (until_decided)."""
        return self.likely is not None

    @property
    def first(self) -> Stage:
        return self.stages[0]

    @property
    def cases(self) -> int:
        """Cases at most."""
        return sum(s.cases for s in self.stages)

    @property
    def core_seconds(self) -> float:
        """Core-seconds at most."""
        return sum(s.core_seconds for s in self.stages)

    @property
    def widest(self) -> int:
        """The most cases a stage of known width runs side by side (a refinement's later stages
        depend on the boundaries it finds: their width is not known before)."""
        return max(len(s.seconds) for s in self.stages if s.sized)

    def wall(self, ranks: int) -> float:
        """Wall seconds on ``ranks`` ranks: each stage as the scheduler runs it, one after the other,
        after rank 0 has laid out its cases alone."""
        computing = computing_ranks(ranks)
        return self.creation + sum(makespan(s.seconds, computing) * s.rounds for s in self.stages)

    def fastest(self) -> float:
        """The wall time with a computing rank for every case of the widest stage: no more ranks help."""
        return self.wall(ranks_for(self.widest))

    def suggested_ranks(self) -> int:
        """The fewest ranks whose wall time is within NEAR_FASTEST of :meth:`fastest`."""
        target = NEAR_FASTEST * self.fastest()
        low, high = 1, ranks_for(self.widest)   # wall(ranks) falls with ranks (LPT: up to rounding)
        while low < high:
            middle = (low + high) // 2
            if self.wall(middle) <= target:
                high = middle
            else:
                low = middle + 1
        return low


def makespan(seconds, ranks: int) -> float:
    """When the last of the cases ends on ``ranks`` ranks: longest first, each to the rank free
    first (the scheduler's rule, scheduler.py), all ranks computing."""
    ordered = sorted(seconds, reverse=True)
    if ranks >= len(ordered):
        return ordered[0] if ordered else 0.0
    free = [0.0] * ranks
    for s in ordered:
        heapq.heapreplace(free, free[0] + s)
    return max(free)


def plan(study: Study, step_seconds: Callable, layout_seconds: Callable | None = None,
         classify_seconds: Callable | None = None) -> Plan:
    """The :class:`Plan` of ``study``; ``step_seconds(case)`` is a step's wall seconds (timing.py),
    ``layout_seconds(case)`` and ``classify_seconds(case)`` those of laying a case out and of classifying
    it once ended (timing.py; None: not counted), each measured on the first stage's median case.

    Every case priced to its t_end; with ``until_decided``, ``likely`` prices it to
    DECIDED_AFTER x decided_shear_times shear times (at most t_end)."""
    first = first_cases(study)
    used = {}
    for case in first:
        N = expected_N(case)
        low, high = used.get(N, (math.inf, 0.0))
        s = step_seconds(case)
        used[N] = (min(low, s), max(high, s))
    units = {"grid": 1, "search": len(study.searches), "refine": len(study.refinements)}[study.mode]
    typical = sorted(first, key=lambda case: case.run.t_end / case.run.sample_interval)[len(first) // 2]
    classify = classify_seconds(typical) if classify_seconds else 0.0
    # a staged study's case is classified by the rank that ran it, as soon as it ends (scheduler._verdict)
    verdict = classify if study.mode != "grid" else 0.0
    ceiling = Plan(study.name, study.mode, _stages(study, first, lambda case: case.estimated_steps
                                                   * step_seconds(case) + verdict), used, units)
    cases = ceiling.cases
    layout = layout_seconds(typical) * cases if layout_seconds else 0.0
    ceiling = dataclasses.replace(ceiling, creation=layout, analysis=classify * cases)
    if not study.base.run.until_decided:
        return ceiling
    likely = dataclasses.replace(ceiling, stages=_stages(study, first, lambda case: case.estimated_steps
                                                         * step_seconds(case) * decided_share(case) + verdict))
    return dataclasses.replace(ceiling, likely=likely)


def decided_share(case) -> float:
    """The share of its run to t_end that a case running until decided typically takes."""
    S, run = case.physics.shear_rate, case.run
    if S <= 0:
        return 1.0
    return min(1.0, DECIDED_AFTER * run.decided_shear_times / (S * run.t_end))


def first_cases(study: Study) -> list:
    """The cases of the first stage, search by search (refinement by refinement): every case of
    a grid, the start of each search's range, each refinement's coarse grid."""
    if study.mode == "grid":
        return [c.case for c in study.cases]
    if study.mode == "search":
        return [study.search_case(i, s, "plan").case for i in range(len(study.searches))
                for s in start_rates(study.search)]
    return [study.refine_case(i, x, y, "plan", start=start).case for i in range(len(study.refinements))
            for x, y in coarse_points(study.refine_settings) for start in study.point_starts]


def memory_per_rank(study: Study) -> tuple[int, int]:
    """(bytes a rank of the study's campaign holds at most: run/timing.py rank_bytes, the N it is at): the
    most nodes a case may compute its rates on -- N (N_max where N adapts; in a refinement also the N its
    retries of under-resolved points may reach) times the de-aliasing factor."""
    cases = first_cases(study)
    retries = study.refine_settings.max_N if study.refine else 0
    N = max(round(c.numerics.dealias * max(c.numerics.N, c.numerics.N_max, retries)) for c in cases)
    return rank_bytes(N, any(c.physics.contrast for c in cases)), N


def _stages(study: Study, first: list, seconds: Callable) -> tuple:
    known = tuple(seconds(case) for case in first)
    if study.mode == "grid":
        return (Stage("grid", known),)
    if study.mode == "search":
        return _search_stages(study, known, seconds)
    return _refine_stages(study, known)


def _search_stages(study: Study, first: tuple, seconds) -> tuple:
    search = study.search
    most = min(search.cases_needed(), search.max_cases)
    later_rounds = math.ceil((most - search.points - 1) / search.points)
    if later_rounds <= 0:
        return (Stage("start", first),)
    # a later case may sit anywhere in [low, high]: price it at the mean over a geometric ladder
    ladder = [search.low * (search.high / search.low) ** (j / 8) for j in range(9)]
    typical = [sum(seconds(study.search_case(i, s, "plan").case) for s in ladder) / len(ladder)
               for i in range(len(study.searches))]
    later = tuple(t for t in typical for _ in range(search.points))
    return Stage("start", first), Stage("splits", later, later_rounds)


def _refine_stages(study: Study, first: tuple) -> tuple:
    settings = study.refine_settings
    n = len(coarse_points(settings)) * len(study.point_starts)       # a refinement of attractors: every start
    spare = settings.max_cases - n
    rounds = min(settings.stages_needed() - 1, spare)
    if rounds <= 0:
        return (Stage("coarse grid", first),)
    # the budget left, spread evenly over the splits, at each refinement's mean
    mean = [sum(first[i * n:(i + 1) * n]) / n for i in range(len(study.refinements))]
    each, more = divmod(spare, rounds)
    stages = [Stage("coarse grid", first)]
    if more:
        stages.append(Stage("splits", tuple(m for m in mean for _ in range(each + 1)), more, sized=False))
    stages.append(Stage("splits", tuple(m for m in mean for _ in range(each)), rounds - more, sized=False))
    return tuple(stages)
