"""Regime boundaries over two parameters, traced by refining a coarse grid (pure logic).

Like a search (search.py), a refinement's state is nothing but the outcomes found
so far, ``{(x, y): regime}``; :func:`step` turns them into the points to run next
or a final verdict, so a refinement resumes by replaying its classified cases and
asks for the same points in every run.

* Coordinates: each axis on its own scale, u = log v on a log axis (S), u = v on
  a linear one (psi_bar, Delta, B2); tolerances are widths in u (log(1 + rel) for
  a relative one).
* Start: the coarse grid, every pair of its x and y values.
* Cells: the rectangles of the coarse grid, split in two while they are **mixed**:
  the outcomes at the known points on it (its corners, the points that its
  neighbours' splits put on its edges, any inside it) are not all one regime of
  TT, PT, TU -- two regimes, or one point undecided, failed or at the model's
  limit. A mixed cell is split along an axis on which it is wider than its
  tolerance when an edge along that axis **changes** (two neighbouring known
  points on it differ, or one is not TT, PT or TU): a boundary crosses that edge
  and must be bracketed on it. A boundary that enters and leaves a cell through
  its two opposite edges along the other axis needs no split along this one;
  it is taken as straight across the cell as long as the cell is at most
  ``straight_span`` tolerances wide along it (default 4; 1 splits every mixed
  cell along every wide axis, a quadtree). Where the boundary turns by more
  than a tolerance across a cell, the split puts points of different outcomes
  on the new middle edge, which then changes, and the halves split along it too.
  A split asks for the new corners (edge midpoints, and the centre when it
  splits both ways, in u); once they are known its halves are refined the same way.
* A case that stops as under-resolved (its spectrum outgrew N) says nothing of
  the regime there; with ``max_N`` the point runs again at 2 N (N_max doubled where
  N adapts; and again, while 2 N <= max_N), and until then it counts as not yet run: the cells
  around it wait for it instead of splitting around a failure. Likewise, where N
  adapts, with ``min_resize_tail`` a point whose theta settled steady while its
  pattern kept moving (the creep of a tank-treading pattern on too coarse a grid,
  regimes.CREEPING) runs again with numerics.resize_tail / 100 (and again, while
  that is >= min_resize_tail); with ``min_rtol`` a point left unsettled at the end of
  its run -- theta neither steady nor periodic, or its periodic mean still drifting
  (regimes.UNSETTLED), which a step too loose for the motion can do -- runs again
  with numerics.rtol / 10 (and again, while that is >= min_rtol). Every run of a
  point counts against ``max_cases``.
* Stop when no mixed cell needs a split (``converged``: every crossing
  bracketed to the tolerances), or when ``max_cases`` points are spent (``budget
  spent``: the widest mixed cells are split first, so the budget goes where
  the brackets are widest).

What it cannot see: a region that falls between the points of a cell whose
known outcomes all agree (an island smaller than a coarse cell that no coarse
point hits): the coarse grid sets the smallest feature that is found; and along
a boundary, a bulge narrower than ``straight_span`` tolerances between two
crossings at the same height.

The boundary (:func:`boundary`) is read off the finest cells: every cell edge
whose two ends have different outcomes brackets a crossing, located at the
edge's middle (in u) to half its width; a crossing with an end that is
undecided, failed or at the model's limit is **blurry** (which side it lies on is
unknown). :func:`polylines` chains the crossings of each pair of outcomes into
lines for a figure or a CSV file.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from hpcves.analysis.regimes import PT, TT, TU
from hpcves.config import check_type, clean_number, refuse_unknown
from hpcves.model.params import ConfigError

CONVERGED, RUNNING, BUDGET = "converged", "running", "budget spent"
#: a creeping point runs again with its numerics.resize_tail divided by this: its creep falls as the
#: tail to a power 0.6-0.9 (docs/numerics.md), so by 16-60 times
CREEP_TIGHTENING = 100.0
#: what an unsettled case's numerics.rtol is divided by when it runs again (``min_rtol``): a tenth, ~3x the steps
RTOL_TIGHTENING = 10.0
DECIDED = (TT, PT, TU)
#: an outcome of several regimes at one point (a refinement of attractors: its starts reached them all)
JOINT = "+"


def decided(outcome: str) -> bool:
    """Whether an outcome is a regime, or (refine.attractors) a set of regimes joined by JOINT."""
    return all(part in DECIDED for part in outcome.split(JOINT))


def joint(regimes) -> str:
    """The outcome of a point run from several starts: their regimes, each once, sorted and joined
    ("PT+TT"); the first outcome that is not a regime where any run is undecided, failed or at the
    model's limit (the point then says nothing sure of what coexists there)."""
    regimes = list(regimes)
    for regime in regimes:
        if regime not in DECIDED:
            return regime
    return JOINT.join(sorted(set(regimes)))


@dataclass(frozen=True)
class Axis:
    """One parameter of the plane: its coarse values and how finely to bracket a boundary on it."""

    key: str
    values: tuple             # the coarse grid, increasing
    tolerance: float          # a width in u: absolute on a linear axis, log(1 + rel) on a log one
    log: bool = False

    def __post_init__(self):
        if len(self.values) < 2 or any(b <= a for a, b in zip(self.values, self.values[1:])):
            raise ConfigError(f"refine: {self.key} needs at least two increasing values, got {list(self.values)}")
        if self.log and self.values[0] <= 0:
            raise ConfigError(f"refine: {self.key} on a log scale needs positive values, got {list(self.values)}")
        if not self.tolerance > 0:
            raise ConfigError(f"refine: the tolerance on {self.key} must be > 0, got {self.tolerance}")

    def u(self, value: float) -> float:
        return math.log(value) if self.log else float(value)

    def value(self, u: float) -> float:
        """The parameter at coordinate u, rounded to 12 significant digits: the same in every run."""
        return clean_number(math.exp(u) if self.log else u)

    def full_grid_points(self) -> int:
        """Values a regular grid needs on this axis to have every interval within the tolerance."""
        return 1 + sum(2 ** _halvings(self.u(b) - self.u(a), self.tolerance)
                       for a, b in zip(self.values, self.values[1:]))


def _halvings(width: float, tolerance: float) -> int:
    """Times an interval of ``width`` is halved until it is within ``tolerance``."""
    return max(0, math.ceil(math.log2(width / tolerance) - 1e-12))


@dataclass(frozen=True)
class RefineSettings:
    """The plane, the tolerances, the budget of one refinement, and how far a boundary is taken as straight."""

    x: Axis
    y: Axis
    max_cases: int = 200
    straight_span: float = 4.0    # widest a cell stays along a boundary that crosses it, in tolerances
    max_N: int = 0                # an under-resolved case runs again at 2 N while that is at most max_N (0: never)
    min_resize_tail: float = 0.0  # a creeping case runs again at resize_tail / 100 while that is at least this
    min_rtol: float = 0.0         # an unsettled case runs again at rtol / 10 while that is at least this

    def __post_init__(self):
        if self.x.key == self.y.key:
            raise ConfigError(f"refine: the two axes are both {self.x.key}")
        coarse = len(self.x.values) * len(self.y.values)
        if self.max_cases < coarse:
            raise ConfigError(f"refine.max_cases = {self.max_cases}: fewer than the {coarse} points of the "
                              "coarse grid")
        if not self.straight_span >= 1:
            raise ConfigError(f"refine.straight_span = {self.straight_span}: must be >= 1 (1: every mixed cell "
                              "is split to the tolerances both ways)")

    def retry_N(self, N: int) -> int | None:
        """The N at which a point runs again after its case stopped as under-resolved at ``N``: 2 N,
        while that is at most ``max_N`` (None: it stays failed)."""
        return 2 * N if 0 < 2 * N <= self.max_N else None

    def retry_tail(self, resize_tail: float) -> float | None:
        """The numerics.resize_tail with which a point runs again after its case crept at ``resize_tail``:
        resize_tail / CREEP_TIGHTENING, while that is at least ``min_resize_tail`` (None: it stays undecided)."""
        tighter = resize_tail / CREEP_TIGHTENING
        return tighter if self.min_resize_tail > 0 and tighter >= self.min_resize_tail * (1 - 1e-9) else None

    def retry_rtol(self, rtol: float) -> float | None:
        """The numerics.rtol with which a point runs again after its case stayed unsettled at ``rtol``
        (regimes.UNSETTLED): rtol / RTOL_TIGHTENING, while that is at least ``min_rtol`` (None: it stays
        undecided)."""
        tighter = rtol / RTOL_TIGHTENING
        return tighter if self.min_rtol > 0 and tighter >= self.min_rtol * (1 - 1e-9) else None

    def log_keys(self) -> tuple:
        """The parameters of the plane on a log scale."""
        return tuple(a.key for a in (self.x, self.y) if a.log)

    def full_grid_cases(self) -> int:
        """Cases of the regular grid that brackets every boundary to the tolerances everywhere."""
        return self.x.full_grid_points() * self.y.full_grid_points()

    def stages_needed(self) -> int:
        """Stages a refinement takes, about: the coarse grid, then one per halving of a coarse cell on
        the way to its finest cells -- along both axes for a quadtree (``straight_span = 1``), one after
        the other otherwise (a cell splits along a boundary only once the boundary shows it turns)."""
        halvings = [max(_halvings(a.u(hi) - a.u(lo), a.tolerance) for lo, hi in zip(a.values, a.values[1:]))
                    for a in (self.x, self.y)]
        return 1 + (max(halvings) if self.straight_span == 1 else sum(halvings))


@dataclass(frozen=True)
class Cell:
    """A rectangle in (u_x, u_y); its corners are points of the refinement."""

    x0: float
    x1: float
    y0: float
    y1: float

    def corners(self, settings: RefineSettings) -> tuple:
        return tuple(point(settings, x, y) for x in (self.x0, self.x1) for y in (self.y0, self.y1))

    def wide(self, settings: RefineSettings, tolerances: float = 1.0) -> tuple[bool, bool]:
        """Along which axes the cell is wider than ``tolerances`` times its tolerance."""
        return (self.x1 - self.x0 > tolerances * settings.x.tolerance * (1 + 1e-9),
                self.y1 - self.y0 > tolerances * settings.y.tolerance * (1 + 1e-9))

    def edges(self) -> tuple:
        """((the two edges along x), (the two along y)), each as its two ends in u."""
        return ((((self.x0, self.y0), (self.x1, self.y0)), ((self.x0, self.y1), (self.x1, self.y1))),
                (((self.x0, self.y0), (self.x0, self.y1)), ((self.x1, self.y0), (self.x1, self.y1))))

    def halves(self, split_x: bool, split_y: bool) -> tuple:
        """The cells it splits into (2 or 4) along the axes asked for."""
        xs = (self.x0, 0.5 * (self.x0 + self.x1), self.x1) if split_x else (self.x0, self.x1)
        ys = (self.y0, 0.5 * (self.y0 + self.y1), self.y1) if split_y else (self.y0, self.y1)
        return tuple(Cell(a, b, c, d) for a, b in zip(xs, xs[1:]) for c, d in zip(ys, ys[1:]))

    def size(self, settings: RefineSettings) -> float:
        """Its width in tolerances along the wider axis: how far it is from done."""
        return max((self.x1 - self.x0) / settings.x.tolerance, (self.y1 - self.y0) / settings.y.tolerance)


#: default tolerances of ``[refine]``: relative on S and lambda (10 %), absolute on the others
DEFAULT_TOLERANCE = {"shear_rate": 0.1, "psi_bar": 0.05, "excess_length": 0.05, "B2": 0.05, "viscosity_ratio": 0.1}
#: the parameters refined on a log scale (S and lambda span decades); the others are linear
LOG_KEYS = ("shear_rate", "viscosity_ratio")


@dataclass(frozen=True)
class RefinePlan:
    """``[refine]`` of a campaign file: the plane, the tolerances, the budget of each refinement::

        [refine]
        axes = ["shear_rate", "psi_bar"]               # default: the first two swept keys
        tolerance = { shear_rate = 0.1, psi_bar = 0.05 }   # relative on S and lambda, absolute otherwise
        max_cases = 150                                # per refinement (coarse grid included)
        straight_span = 4       # a boundary crossing a cell is taken as straight over at most 4 tolerances
        max_N = 256             # an under-resolved case runs again at 2 N, up to N = 256 (default: never)
        min_resize_tail = 1e-6  # N = "auto": a creeping case runs again with resize_tail / 100, down to
                                # 1e-6 (default: never)
        min_rtol = 1e-4         # an adaptive step: a case left unsettled (theta neither steady nor
                                # periodic, or still drifting, at its end) runs again with rtol / 10,
                                # down to 1e-4 (default: never)
        attractors = true       # with [starts]: every point runs from every start, and a cell is mixed
                                # where the sets of regimes they reach differ (coexistence is traced)

    The coarse grid is the ``[sweep]`` values of the two axes; every combination of the
    other swept keys gets a refinement of its own.
    """

    axes: tuple               # (x key, y key)
    tolerance: tuple          # ((key, tolerance), ...) for the two axes, in the user's terms
    max_cases: int = 200
    straight_span: float = 4.0
    max_N: int = 0            # 0: an under-resolved case is not run again
    attractors: bool = False  # with [starts]: a point's outcome is the set of regimes its starts reach
    min_resize_tail: float = 0.0   # 0: a creeping case is not run again
    min_rtol: float = 0.0          # 0: an unsettled case is not run again

    def settings(self, sweep: dict) -> RefineSettings:
        """The RefineSettings of one refinement over the ``sweep`` values of the axes."""
        tolerance = dict(self.tolerance)

        def axis(key):
            log = key in LOG_KEYS
            return Axis(key, tuple(sorted(sweep[key])), math.log1p(tolerance[key]) if log else tolerance[key], log)

        return RefineSettings(axis(self.axes[0]), axis(self.axes[1]), self.max_cases, self.straight_span,
                              self.max_N, self.min_resize_tail, self.min_rtol)

    @classmethod
    def from_dict(cls, values: dict, sweep: dict, where: str = "[refine]") -> "RefinePlan":
        """From the TOML table and the study's ``{key: values}`` sweep (validated against each other)."""
        refuse_unknown(values, ("axes", "tolerance", "max_cases", "straight_span", "max_N", "attractors",
                                "min_resize_tail", "min_rtol"), where)
        swept = [k for k, v in sweep.items() if len(v) > 1]
        axes = values.get("axes", swept[:2])
        if (not isinstance(axes, list | tuple) or len(axes) != 2
                or not all(isinstance(a, str) for a in axes)):
            raise ConfigError(f"{where}: axes = {axes!r}: give the two swept parameters of the plane, "
                              'e.g. axes = ["shear_rate", "psi_bar"]')
        for key in axes:
            if key not in sweep:
                raise ConfigError(f"{where}: axis {key} is not in [sweep] (its values there are the coarse grid)")
            if len(sweep[key]) < 2:
                raise ConfigError(f"{where}: axis {key} has {len(sweep[key])} value in [sweep]; the coarse "
                                  "grid needs at least two")
        if axes[0] == axes[1]:
            raise ConfigError(f"{where}: the two axes are both {axes[0]}")
        given = values.get("tolerance", {})
        if not isinstance(given, dict):
            raise ConfigError(f"{where}: tolerance = {given!r}: must be a table, e.g. "
                              "{ shear_rate = 0.1, psi_bar = 0.05 }")
        extra = sorted(set(given) - set(axes))
        if extra:
            raise ConfigError(f"{where}: tolerance for {', '.join(extra)}, which is not an axis ({', '.join(axes)})")
        tolerance = []
        for key in axes:
            value = check_type(f"refine.tolerance.{key}", given.get(key, DEFAULT_TOLERANCE[key]), float)
            if not value > 0:
                raise ConfigError(f"{where}: tolerance.{key} = {value}: must be > 0"
                                  + (" (relative: 0.1 brackets S to 10 %)" if key in LOG_KEYS else ""))
            tolerance.append((key, value))
        max_cases = check_type("refine.max_cases", values.get("max_cases", 200), int)
        straight_span = check_type("refine.straight_span", values.get("straight_span", 4.0), float)
        max_N = check_type("refine.max_N", values.get("max_N", 0), int)
        if max_N < 0:
            raise ConfigError(f"{where}: max_N = {max_N}: must be >= 0 (0: an under-resolved case is not run again)")
        attractors = check_type("refine.attractors", values.get("attractors", False), bool)
        min_resize_tail = check_type("refine.min_resize_tail", values.get("min_resize_tail", 0.0), float)
        if not 0 <= min_resize_tail < 1:
            raise ConfigError(f"{where}: min_resize_tail = {min_resize_tail:g}: must lie in [0, 1) (0: a creeping "
                              "case is not run again)")
        min_rtol = check_type("refine.min_rtol", values.get("min_rtol", 0.0), float)
        if not 0 <= min_rtol < 1:
            raise ConfigError(f"{where}: min_rtol = {min_rtol:g}: must lie in [0, 1) (0: an unsettled case is not "
                              "run again)")
        plan = cls(tuple(axes), tuple(tolerance), max_cases, straight_span, max_N, attractors, min_resize_tail,
                   min_rtol)
        try:
            plan.settings(sweep)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {str(exc).removeprefix('refine: ')}") from None
        return plan


def point(settings: RefineSettings, ux: float, uy: float) -> tuple[float, float]:
    """The parameter values (x, y) of the point at coordinates (ux, uy)."""
    return settings.x.value(ux), settings.y.value(uy)


@dataclass(frozen=True)
class RefineState:
    status: str                     # converged, running, budget spent
    next_points: tuple              # (x, y) to run now (empty unless running)
    cells: tuple                    # the finest mixed cells so far
    reason: str


def coarse_points(settings: RefineSettings) -> tuple:
    return tuple((settings.x.value(settings.x.u(x)), settings.y.value(settings.y.u(y)))
                 for x in settings.x.values for y in settings.y.values)


def step(settings: RefineSettings, results: dict, spent: int | None = None) -> RefineState:
    """The next points to run given ``results`` = {(x, y): outcome} of the classified cases; ``spent``:
    the cases run so far, when more than the points (a point run again at a larger N counts each time).

    A point left out of ``results`` is one still to run: a point whose case is to run again at a
    larger N or a tighter resize_tail (:meth:`RefineSettings.retry_N`, :meth:`RefineSettings.retry_tail`)
    is left out, and asked for again when a cell needs it."""
    spent = len(results) if spent is None else spent
    missing = tuple(p for p in coarse_points(settings) if p not in results)
    if missing:
        return RefineState(RUNNING, missing, (), f"the coarse grid: {len(missing)} points")
    leaves, wanted = _mixed_leaves(settings, results)
    if not wanted:
        return RefineState(CONVERGED, (), tuple(leaves),
                           f"every boundary bracketed to the tolerances ({spent} cases)")
    left = settings.max_cases - spent
    if left <= 0:
        return RefineState(BUDGET, (), tuple(leaves), f"max_cases = {settings.max_cases} spent with "
                           f"{len(wanted)} mixed cells still to split")
    chosen: list = []
    for _, cell, points in sorted(wanted, key=lambda w: (-w[0], w[1].x0, w[1].y0)):
        new = [p for p in points if p not in chosen]
        if len(chosen) + len(new) > left:
            break
        chosen += new
    if not chosen:
        return RefineState(BUDGET, (), tuple(leaves), f"max_cases = {settings.max_cases}: {left} left, too few "
                           "for the next split")
    return RefineState(RUNNING, tuple(sorted(chosen)), tuple(leaves),
                       f"{len(wanted)} mixed cells to split: {len(chosen)} new points")


def _outcomes_on(cell: Cell, settings: RefineSettings, known: list) -> set:
    """The outcomes of the known points on the closed cell (corners, edges, inside)."""
    eps_x, eps_y = 1e-9 * settings.x.tolerance, 1e-9 * settings.y.tolerance
    return {regime for ux, uy, regime in known
            if cell.x0 - eps_x <= ux <= cell.x1 + eps_x and cell.y0 - eps_y <= uy <= cell.y1 + eps_y}


def _mixed(outcomes: set) -> bool:
    return len(outcomes) > 1 or not all(decided(o) for o in outcomes)


def _changes(settings, results: dict, known: list, edge) -> bool:
    """Whether a boundary crosses the edge: two neighbouring known points on it differ, or one is
    not TT, PT or TU."""
    return any(results[p] != results[q] or not decided(results[p])
               for p, q in _edge_pieces(settings, known, *edge))


def _splits(cell: Cell, settings: RefineSettings, results: dict, known: list) -> tuple[bool, bool]:
    """Along which axes a mixed cell is split: where it is wider than the tolerance and an edge along
    that axis changes, or it is wider than straight_span tolerances."""
    wide = cell.wide(settings)
    too_long = cell.wide(settings, settings.straight_span)
    return tuple(w and (long or any(_changes(settings, results, known, e) for e in edges))
                 for w, long, edges in zip(wide, too_long, cell.edges()))


def _mixed_leaves(settings: RefineSettings, results: dict):
    """(the finest mixed cells, [(size, cell, its split's points)] for the mixed cells that need a
    split whose points have not all been run)."""
    known = _coordinates(settings, results)
    outcomes = [(ux, uy, results[p]) for ux, uy, p in known]
    xs = [settings.x.u(v) for v in settings.x.values]
    ys = [settings.y.u(v) for v in settings.y.values]
    todo = [Cell(a, b, c, d) for a, b in zip(xs, xs[1:]) for c, d in zip(ys, ys[1:])]
    leaves, wanted = [], []
    while todo:
        cell = todo.pop()
        if not _mixed(_outcomes_on(cell, settings, outcomes)):
            continue
        splits = _splits(cell, settings, results, known)
        if not any(splits):
            leaves.append(cell)
            continue
        halves = cell.halves(*splits)
        needed = sorted({p for half in halves for p in half.corners(settings)} - set(results))
        if needed:
            leaves.append(cell)
            wanted.append((cell.size(settings), cell, needed))
        else:
            todo.extend(halves)
    leaves.sort(key=lambda c: (c.x0, c.y0))
    return leaves, wanted


# ---------------------------------------------------------------------- the boundary
@dataclass(frozen=True)
class Crossing:
    """Where a boundary crosses the edge between two points of different outcomes."""

    pair: str                  # the two outcomes, sorted: "PT|TT"
    x: float                   # the edge's middle (in u)
    y: float
    x_low: float               # the edge's ends: the bracket
    x_high: float
    y_low: float
    y_high: float
    blurry: bool               # one end is not TT, PT or TU


def boundary(settings: RefineSettings, results: dict, cells=None) -> list[Crossing]:
    """The crossings on the edges of the finest mixed cells (``cells``, default: step's)."""
    found, _ = _crossings(settings, results, cells)
    return sorted(found.values(), key=lambda c: (c.pair, c.x, c.y))


def _crossings(settings, results, cells):
    """({edge: Crossing}, [the edges with a crossing, per cell]) of the finest mixed cells."""
    if cells is None:
        cells, _ = _mixed_leaves(settings, results)
    known = _coordinates(settings, results)
    found, per_cell = {}, []
    for cell in cells:
        mine = []
        for edge in (e for along in cell.edges() for e in along):
            for a, b in _edge_pieces(settings, known, *edge):
                ra, rb = results[a], results[b]
                if ra == rb:
                    continue
                key = (min(a, b), max(a, b))
                if key not in found:
                    ua = (settings.x.u(a[0]), settings.y.u(a[1]))
                    ub = (settings.x.u(b[0]), settings.y.u(b[1]))
                    mx, my = point(settings, 0.5 * (ua[0] + ub[0]), 0.5 * (ua[1] + ub[1]))
                    found[key] = Crossing("|".join(sorted((ra, rb))), mx, my, min(a[0], b[0]), max(a[0], b[0]),
                                          min(a[1], b[1]), max(a[1], b[1]), not (decided(ra) and decided(rb)))
                mine.append(key)
        per_cell.append(mine)
    return found, per_cell


def _coordinates(settings: RefineSettings, results: dict) -> list:
    """(u_x, u_y, point) of every known point."""
    return [(settings.x.u(p[0]), settings.y.u(p[1]), p) for p in results]


def _edge_pieces(settings, known, a, b):
    """The consecutive ``known`` points (_coordinates) along the edge from a to b (u coordinates), as
    pairs of points (a point's u, from its value rounded to 12 digits, is within 1e-9 tolerances of
    the lattice's)."""
    eps_x, eps_y = 1e-9 * settings.x.tolerance, 1e-9 * settings.y.tolerance
    horizontal = a[1] == b[1]
    on_edge = []
    for ux, uy, p in known:
        if horizontal and abs(uy - a[1]) <= eps_y and a[0] - eps_x <= ux <= b[0] + eps_x:
            on_edge.append((ux, p))
        elif not horizontal and abs(ux - a[0]) <= eps_x and a[1] - eps_y <= uy <= b[1] + eps_y:
            on_edge.append((uy, p))
    on_edge.sort()
    return [(p, q) for (_, p), (_, q) in zip(on_edge, on_edge[1:])]


def polylines(settings: RefineSettings, results: dict, cells=None) -> list[tuple[str, list[Crossing]]]:
    """The crossings of each pair of outcomes chained into lines, as marching squares does: two
    crossings of one pair on the edges of one cell are neighbours along the boundary. Each line
    runs from an end (a crossing with one neighbour; any crossing of a closed loop) to the
    nearest unvisited neighbour until none is left; a loop's last crossing neighbours its first."""
    found, per_cell = _crossings(settings, results, cells)
    links = {key: set() for key in found}
    for keys in per_cell:
        for a in keys:
            for b in keys:
                if a != b and found[a].pair == found[b].pair:
                    links[a].add(b)

    def gap(a, b):
        return math.hypot((settings.x.u(found[a].x) - settings.x.u(found[b].x)) / settings.x.tolerance,
                          (settings.y.u(found[a].y) - settings.y.u(found[b].y)) / settings.y.tolerance)

    lines, seen = [], set()
    order = sorted(found, key=lambda k: (found[k].pair, len(links[k]) != 1, found[k].x, found[k].y))
    for start in order:
        if start in seen:
            continue
        line = [start]
        seen.add(start)
        while True:
            ahead = [k for k in links[line[-1]] if k not in seen]
            if not ahead:
                break
            nearest = min(ahead, key=lambda k: (gap(line[-1], k), found[k].x, found[k].y))
            line.append(nearest)
            seen.add(nearest)
        lines.append((found[start].pair, [found[k] for k in line]))
    return lines


# ---------------------------------------------------------------------- decided regions (the figures)
def regions(settings: RefineSettings, results: dict) -> list[tuple[tuple, str]]:
    """The cells that the cases around them decide: every cell of the coarse grid, split as the
    refinement split it, whose four corners have been run and whose known points (corners, edges,
    inside) all share one decided outcome -- as ((x0, x1, y0, y1) in parameter values, outcome).
    Mixed cells, and cells with a corner not run, are left out: the boundaries lie in them."""
    known = _coordinates(settings, results)
    outcomes = [(ux, uy, results[p]) for ux, uy, p in known]
    xs = [settings.x.u(v) for v in settings.x.values]
    ys = [settings.y.u(v) for v in settings.y.values]
    todo = [Cell(a, b, c, d) for a, b in zip(xs, xs[1:]) for c, d in zip(ys, ys[1:])]
    out = []
    while todo:
        cell = todo.pop()
        corners = cell.corners(settings)
        if not all(p in results for p in corners):
            continue
        found = _outcomes_on(cell, settings, outcomes)
        if not _mixed(found):
            (x0, y0), (x1, y1) = point(settings, cell.x0, cell.y0), point(settings, cell.x1, cell.y1)
            out.append(((x0, x1, y0, y1), found.pop()))
            continue
        splits = _splits(cell, settings, results, known)
        if any(splits):
            todo.extend(cell.halves(*splits))
    out.sort(key=lambda r: (r[0][0], r[0][2]))
    return out
