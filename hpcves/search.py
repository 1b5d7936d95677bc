"""The critical shear rate S_C: bracket it between a TT and a PT case, then bisect (pure logic).

One search runs along S for fixed (psi_bar, Delta, B2). Its state is nothing
but the regimes found so far, ``{S: regime}``; :func:`step` turns that into
the next shear rates to run or a final verdict. Being a pure function of the
results, a search resumes by replaying them, and the cases it asks for are
the same in every run.

* Start: the two ends of ``[low, high]``.
* Bracket: ``lo`` = the largest TT shear rate below every PT/TU one,
  ``hi`` = the smallest PT/TU one above ``lo``.
* Bisect geometrically (S spans decades): the next case is sqrt(lo hi),
  until ``hi / lo - 1 <= rel_tol``; then S_C = sqrt(lo hi), bracket [lo, hi].
* Stop without S_C, saying why, when: the range does not bracket a
  transition (TT everywhere: S_C > high; PT at ``low`` already: S_C < low);
  a case inside the bracket is undecided or failed; TT is found above a PT
  case (no single transition); or ``max_cases`` cases were spent.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from .params import ConfigError
from .regimes import PT, TT, TU

CONVERGED, RUNNING, UNBRACKETED, STOPPED = "converged", "running", "not bracketed", "stopped"


@dataclass(frozen=True)
class SearchSettings:
    """``[search]`` of a campaign file: the S range and the relative tolerance on S_C."""

    low: float
    high: float
    rel_tol: float = 0.02
    max_cases: int = 16

    def __post_init__(self):
        if not 0 < self.low < self.high:
            raise ConfigError(f"search: need 0 < low < high, got low = {self.low}, high = {self.high}")
        if not 0 < self.rel_tol < 1:
            raise ConfigError(f"search.rel_tol = {self.rel_tol}: must lie in (0, 1)")
        if self.max_cases < 2:
            raise ConfigError(f"search.max_cases = {self.max_cases}: must be >= 2")

    def cases_needed(self) -> int:
        """Cases a search takes to converge from [low, high]: 2 ends + ceil(log2(log(high/low)/log(1+tol)))."""
        return 2 + max(0, math.ceil(math.log2(math.log(self.high / self.low) / math.log1p(self.rel_tol))))


@dataclass(frozen=True)
class SearchState:
    status: str                    # converged, running, not bracketed, stopped
    next_shear_rates: tuple        # to run now (empty unless running)
    low: float                     # bracket: the largest TT below the transition (nan if none)
    high: float                    # the smallest PT/TU above it (nan if none)
    critical: float                # sqrt(low high) once converged, else nan
    reason: str


def _clean(value: float) -> float:
    return float(f"{value:.12g}")


def step(settings: SearchSettings, results: dict) -> SearchState:
    """The state of one search given ``results`` = {shear rate: regime} of its finished cases."""
    nan = float("nan")
    missing = tuple(s for s in (settings.low, settings.high) if s not in results)
    if missing:
        return SearchState(RUNNING, missing, nan, nan, nan, "starting: both ends of the range")
    rates = sorted(results)
    above = [s for s in rates if results[s] in (PT, TU)]
    if not above:
        undecided = [s for s in rates if results[s] != TT]
        if undecided:
            return SearchState(STOPPED, (), nan, nan, nan,
                               f"no PT found, and S = {_list(undecided)} undecided")
        return SearchState(UNBRACKETED, (), settings.high, nan, nan,
                           f"TT up to S = {settings.high:g}: S_C > {settings.high:g}")
    hi = above[0]
    below = [s for s in rates if s < hi]
    if not below or results[settings.low] in (PT, TU):
        return SearchState(UNBRACKETED, (), nan, hi, nan,
                           f"{results[settings.low]} already at S = {settings.low:g}: S_C < {settings.low:g}")
    lo = below[-1]
    if results[lo] != TT:
        return SearchState(STOPPED, (), nan, hi, nan, f"S = {lo:g} below the first PT is {results[lo]}")
    wrong = [s for s in rates if s > hi and results[s] == TT]
    if wrong:
        return SearchState(STOPPED, (), lo, hi, nan,
                           f"TT again at S = {_list(wrong)} above PT at S = {hi:g}: not a single transition")
    if hi / lo - 1 <= settings.rel_tol:
        critical = math.sqrt(lo * hi)
        return SearchState(CONVERGED, (), lo, hi, critical,
                           f"S_C = {critical:.4g} in [{lo:g}, {hi:g}] ({len(results)} cases)")
    if len(results) >= settings.max_cases:
        return SearchState(STOPPED, (), lo, hi, nan, f"max_cases = {settings.max_cases} spent; S_C in "
                                                     f"[{lo:g}, {hi:g}]")
    return SearchState(RUNNING, (_clean(math.sqrt(lo * hi)),), lo, hi, nan, f"bracket [{lo:g}, {hi:g}]")


def _list(values) -> str:
    return ", ".join(f"{v:g}" for v in values)
