"""The critical shear rate S_C: bracket it between a TT and a PT case, then bisect (pure logic).

One search runs along S for fixed (psi_bar, Delta, B2) -- or, with ``along =
"viscosity_ratio"``, along lambda for fixed (psi_bar, Delta, B2, S), where
lambda_C bounds tank-treading from above as S_C does (TT below, PT/TU above);
what is said of S below holds of lambda then. Its state is nothing
but the regimes found so far, ``{S: regime}``; :func:`step` turns that into
the next shear rates to run or a final verdict. Being a pure function of the
results, a search resumes by replaying them, and the cases it asks for are
the same in every run.

* Start: the two ends of ``[low, high]`` (and ``points - 1`` shear rates
  spaced geometrically between them).
* Bracket: ``lo`` = the largest TT shear rate below every PT/TU one,
  ``hi`` = the smallest PT/TU one above ``lo``.
* Bisect geometrically (S spans decades): the next case is sqrt(lo hi) --
  or, with ``points = k``, the k rates that split [lo, hi] into k + 1 equal
  ratios, run side by side (for many ranks and few searches) -- until
  ``hi / lo - 1 <= rel_tol``; the result is the bracket [lo, hi] (its geometric
  centre sqrt(lo hi) is kept as ``SearchState.centre``; a best estimate inside the
  bracket comes from the cases' periods and inclinations, :func:`estimate_critical`).
* Stop without S_C, saying why, when: the range does not bracket a
  transition (TT everywhere: S_C > high; PT at ``low`` already: S_C < low);
  a case inside the bracket is undecided, failed or at the model's limit; TT is found above a PT
  case (no single transition); or ``max_cases`` cases were spent.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

from hpcves.analysis.regimes import PT, TT, TU
from hpcves.config import clean_number, from_table
from hpcves.model.params import ConfigError

CONVERGED, RUNNING, UNBRACKETED, STOPPED = "converged", "running", "not bracketed", "stopped"
#: how a critical value was found where nothing better than the bracket is known
CENTRE = "the bracket's geometric centre"


def centre_only(found_from) -> bool:
    """Whether a table's ``S_C_from`` (``lambda_C_from``) says its critical value is only the bracket's centre."""
    return str(found_from).startswith(CENTRE)

#: what a search may run along -> (its symbol, the column of its critical value, the stem of its tables)
AXES = {"shear_rate": ("S", "S_C", "critical_shear"), "viscosity_ratio": ("lambda", "lambda_C", "critical_lambda")}


@dataclass(frozen=True)
class SearchSettings:
    """``[search]`` of a campaign file: the parameter searched along (``along``, the shear rate
    unless said), its range and the relative tolerance on its critical value."""

    low: float
    high: float
    rel_tol: float = 0.02
    max_cases: int = 16
    points: int = 1                # shear rates per search per stage (k-section; 1 = bisection)
    along: str = "shear_rate"

    def __post_init__(self):
        if self.along not in AXES:
            raise ConfigError(f"search.along = {self.along!r}: a search runs along one of {', '.join(AXES)}")
        if not 0 < self.low < self.high:
            raise ConfigError(f"search: need 0 < low < high, got low = {self.low}, high = {self.high}")
        if not 0 < self.rel_tol < 1:
            raise ConfigError(f"search.rel_tol = {self.rel_tol}: must lie in (0, 1)")
        if self.points < 1:
            raise ConfigError(f"search.points = {self.points}: must be >= 1")
        if self.max_cases < self.points + 1:
            raise ConfigError(f"search.max_cases = {self.max_cases}: must be >= points + 1 = {self.points + 1}")

    @property
    def symbol(self) -> str:
        """S or lambda."""
        return AXES[self.along][0]

    @property
    def column(self) -> str:
        """S_C or lambda_C: the column of the critical value in the tables."""
        return AXES[self.along][1]

    @property
    def stem(self) -> str:
        """critical_shear or critical_lambda: the name of the tables."""
        return AXES[self.along][2]

    def cases_needed(self) -> int:
        """Cases a search takes at most to converge from [low, high].

        The start (points + 1 cases) leaves a bracket of ratio (high/low)^(1/points);
        each stage divides its logarithm by points + 1. For bisection this is
        2 + ceil(log2(log(high/low) / log(1 + rel_tol))).
        """
        ratio = math.log(self.high / self.low) / self.points / math.log1p(self.rel_tol)
        stages = max(0, math.ceil(math.log(ratio) / math.log(self.points + 1) - 1e-12)) if ratio > 1 else 0
        return self.points + 1 + stages * self.points

    def stages_needed(self) -> int:
        """Stages (rounds of cases run side by side) a search takes at most: the start plus the splits."""
        return 1 + (self.cases_needed() - self.points - 1) // self.points

    @classmethod
    def from_dict(cls, values: dict, where: str = "[search]") -> "SearchSettings":
        unknown = set(values) - {f.name for f in fields(cls)}       # from_table names them
        missing = [k for k in ("low", "high") if k not in values]
        if missing and not unknown:
            raise ConfigError(f"{where}: give {' and '.join(missing)} (the range of "
                              f"{AXES.get(values.get('along', 'shear_rate'), ('S',))[0]} to search)")
        return from_table(cls, values, where, "search")


@dataclass(frozen=True)
class SearchState:
    status: str                    # converged, running, not bracketed, stopped
    next_values: tuple             # to run now (empty unless running)
    low: float                     # bracket: the largest TT below the transition (nan if none)
    high: float                    # the smallest PT/TU above it (nan if none)
    centre: float                  # sqrt(low high) once converged, else nan (no estimate: estimate_critical)
    reason: str


def between(low: float, high: float, k: int) -> tuple:
    """The k shear rates that split [low, high] into k + 1 equal ratios (k = 1: sqrt(low high))."""
    if k == 1:
        return (clean_number(math.sqrt(low * high)),)
    return tuple(clean_number(low * (high / low) ** (i / (k + 1))) for i in range(1, k + 1))


def start_rates(settings: SearchSettings) -> tuple:
    """The shear rates of a search's first stage: both ends and points - 1 between them."""
    inner = between(settings.low, settings.high, settings.points - 1) if settings.points > 1 else ()
    return (settings.low, *inner, settings.high)


def step(settings: SearchSettings, results: dict) -> SearchState:
    """The state of one search given ``results`` = {shear rate: regime} of its finished cases.

    A regime other than TT, PT or TU (undecided, failed, model limit) is never taken as either side.
    """
    nan = float("nan")
    S, S_C = settings.symbol, settings.column
    missing = tuple(s for s in start_rates(settings) if s not in results)
    if missing:
        return SearchState(RUNNING, missing, nan, nan, nan, "starting: both ends of the range")
    rates = sorted(results)
    above = [s for s in rates if results[s] in (PT, TU)]
    if not above:
        undecided = [s for s in rates if results[s] != TT]
        if undecided:
            return SearchState(STOPPED, (), nan, nan, nan,
                               f"no PT found, and {S} = {_list(undecided)} undecided")
        return SearchState(UNBRACKETED, (), settings.high, nan, nan,
                           f"TT up to {S} = {settings.high:g}: {S_C} > {settings.high:g}")
    hi = above[0]
    below = [s for s in rates if s < hi]
    if not below or results[settings.low] in (PT, TU):
        return SearchState(UNBRACKETED, (), nan, hi, nan,
                           f"{results[settings.low]} already at {S} = {settings.low:g}: {S_C} < {settings.low:g}")
    lo = below[-1]
    if results[lo] != TT:
        return SearchState(STOPPED, (), nan, hi, nan, f"{S} = {lo:g} below the first PT is {results[lo]}")
    wrong = [s for s in rates if s > hi and results[s] == TT]
    if wrong:
        return SearchState(STOPPED, (), lo, hi, nan,
                           f"TT again at {S} = {_list(wrong)} above PT at {S} = {hi:g}: not a single transition")
    if hi / lo - 1 <= settings.rel_tol:
        return SearchState(CONVERGED, (), lo, hi, math.sqrt(lo * hi),
                           f"{S_C} in [{lo:g}, {hi:g}] ({len(results)} cases)")
    left = settings.max_cases - len(results)
    if left <= 0:
        return SearchState(STOPPED, (), lo, hi, nan, f"max_cases = {settings.max_cases} spent; {S_C} in "
                                                     f"[{lo:g}, {hi:g}]")
    return SearchState(RUNNING, between(lo, hi, min(settings.points, left)), lo, hi, nan,
                       f"bracket [{lo:g}, {hi:g}]")


def _list(values) -> str:
    return ", ".join(f"{v:g}" for v in values)


@dataclass(frozen=True)
class CriticalEstimate:
    """A best estimate of the critical value inside a converged bracket, and how it was found.

    ``value`` is nan where no extrapolation lands inside the bracket; the bracket stays the result's
    error bar either way (the extrapolations carry errors of their own that nothing here bounds).
    """

    value: float
    method: str            # what ``value`` is, in words, for a table
    extrapolations: tuple  # (what, value) of every extrapolation tried, inside the bracket or not


#: how far from the bracket, in bracket widths, a case may lie and still be extrapolated from
LOCAL_WIDTHS = 5.0


def root_of_square(x1: float, y1: float, x2: float, y2: float) -> float:
    """Where y^2, taken as linear in x through (x1, y1^2) and (x2, y2^2), vanishes: x1 - y1^2 (x2 - x1) /
    (y2^2 - y1^2); nan where y^2 does not change."""
    change = y2 * y2 - y1 * y1
    return x1 - y1 * y1 * (x2 - x1) / change if change != 0 else math.nan


def estimate_critical(low: float, high: float, cases: dict) -> CriticalEstimate:
    """A best estimate of the critical value in the bracket [low, high] from ``cases`` = {value searched
    along: (regime, mean inclination theta, period)} of a search's finished cases.

    Both transitions a search finds end a stationary state at a saddle-node: past it the motion is
    periodic with a period that diverges as T ~ (x - x_C)^(-1/2) (a saddle-node on the invariant
    circle, Strogatz, *Nonlinear Dynamics and Chaos*, sec. 4.3), so the frequency squared 1/T^2 of
    the two PT/TU cases nearest above the bracket, taken as linear in x, vanishes at x_C. Below a
    tank-treading -> tumbling transition the inclination of the stationary state falls to zero
    (Keller & Skalak 1982: sin^2 theta ~ (x_C - x)), so theta^2 of the two TT cases nearest below
    the bracket gives a second estimate. Only cases within ``LOCAL_WIDTHS`` bracket widths of the
    bracket count: the scaling is a local law, and a secant through a far case (a search's first
    stage at ``high``, where T ~ 1/S) would pin the root to the bracket's end. The extrapolations
    that land inside the bracket are averaged with weights 1 / (d1 d2)^2 -- a secant through cases
    at distances d1, d2 from x_C misses a root of c d (1 + a d) by about a d1 d2, so the nearer pair
    counts more; d1 and d2 are measured from the estimate itself, found by iterating from the plain
    mean. One that lands outside the bracket is not used (the scaling does not hold that far).
    """
    rates = sorted(cases)
    reach = LOCAL_WIDTHS * (high - low)
    tried = []                     # (what, root, the two cases it extrapolates from)
    above = [(x, 1.0 / cases[x][2]) for x in rates if high <= x <= high + reach and cases[x][0] in (PT, TU)
             and math.isfinite(cases[x][2]) and cases[x][2] > 0][:2]
    if len(above) == 2 and above[1][1] > above[0][1]:
        tried.append((f"1/T^2 -> 0 above ({cases[above[0][0]][0]})", root_of_square(*above[0], *above[1]),
                      (above[0][0], above[1][0])))
    if cases.get(high, ("",))[0] == TU:
        below = [(x, cases[x][1]) for x in rates if low - reach <= x <= low and cases[x][0] == TT
                 and math.isfinite(cases[x][1]) and cases[x][1] > 0][-2:]
        if len(below) == 2 and below[0][1] > below[1][1]:
            tried.append(("theta^2 -> 0 below (TT)", root_of_square(*below[0], *below[1]),
                          (below[0][0], below[1][0])))
    inside = [(what, x, pair) for what, x, pair in tried if low <= x <= high]
    tried = tuple((what, x) for what, x, _ in tried)
    if not tried:
        return CriticalEstimate(math.nan, f"no two cases on a side within {LOCAL_WIDTHS:g} bracket widths to "
                                          "extrapolate from", ())
    if not inside:
        left = "; ".join(f"{what} gives {x:.4g}" for what, x in tried)
        return CriticalEstimate(math.nan, f"no extrapolation inside the bracket ({left})", tried)
    value = sum(x for _, x, _ in inside) / len(inside)
    for _ in range(8 if len(inside) > 1 else 0):        # the weights measure d1, d2 from the estimate
        weights = [1.0 / max(abs((a - value) * (b - value)), 1e-300) ** 2 for _, _, (a, b) in inside]
        value = sum(w * x for w, (_, x, _) in zip(weights, inside)) / sum(weights)
    method = ", ".join(f"{what}: {x:.4g}" for what, x, _ in inside)
    return CriticalEstimate(value, (method if len(inside) == 1 else f"weighted mean of {method}"), tried)
