"""Distinct attractors among the runs of one parameter point (SPEC section 7).

Where several stable states coexist, runs from different starts settle on different ones. Two runs
reached the same attractor when they have the same regime and the same pattern topology
(analysis/pattern.py) and their mean inclinations -- and periods, where they have one -- agree within
the sum of their error bars (statistical plus time step; an infinite bar: not compared). Runs that
are not decided (undecided, failed,
at the model's limit) reached none that can be named and are left out. Grouping is greedy in the
order given: a run joins the first attractor whose first run it matches.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from hpcves.analysis.pattern import Topology

DECIDED = ("TT", "PT", "TU")


@dataclass(frozen=True)
class Run:
    """One settled run at a parameter point, and the start it came from."""

    start: str
    regime: str
    topology: Topology | None
    theta_mean: float
    theta_err: float            # statistical + time step (nan: not estimated)
    period: float = math.nan
    period_err: float = math.nan


@dataclass(frozen=True)
class Attractor:
    regime: str
    topology: Topology | None
    runs: tuple

    @property
    def starts(self) -> tuple:
        return tuple(dict.fromkeys(run.start for run in self.runs))

    def text(self) -> str:
        first = self.runs[0]
        what = self.regime + (f", {self.topology.text()}" if self.topology is not None else "")
        value = f"period {first.period:.5g}" if math.isfinite(first.period) else f"theta {first.theta_mean:.4f}"
        return f"{what}, {value}: from {', '.join(self.starts)}"


def _agree(a: float, b: float, a_err: float, b_err: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    if math.isinf(a_err) or math.isinf(b_err):          # a quantity that does not tell states apart
        return True
    bar = (a_err if math.isfinite(a_err) else 0.0) + (b_err if math.isfinite(b_err) else 0.0)
    return abs(a - b) <= bar


def same_attractor(a: Run, b: Run) -> bool:
    """Whether two runs settled on the same state (module docstring)."""
    return (a.regime == b.regime and a.topology == b.topology
            and _agree(a.theta_mean, b.theta_mean, a.theta_err, b.theta_err)
            and _agree(a.period, b.period, a.period_err, b.period_err))


def group(runs) -> list[Attractor]:
    """The distinct attractors the decided ``runs`` of one point reached, in the order first reached."""
    found: list[list[Run]] = []
    for run in runs:
        if run.regime not in DECIDED:
            continue
        for members in found:
            if same_attractor(members[0], run):
                members.append(run)
                break
        else:
            found.append([run])
    return [Attractor(members[0].regime, members[0].topology, tuple(members)) for members in found]
