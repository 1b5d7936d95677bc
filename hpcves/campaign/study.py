"""Campaign files (TOML) -> the list of cases of a study, validated up front.

A campaign file is a case file (the base case: ``[physics]``, ``[numerics]``,
``[run]``, SPEC defaults for whatever is left out) plus two tables::

    [campaign]
    name = "delta0194"                 # default: the file name without .toml
    output = "out/delta0194.h5"        # default: <name>.h5; relative to the working directory
    shear_times = 200                  # t_end = max(t_end_min, shear_times / S) ...
    t_end_min = 2.0
    # t_end = 5.0                      # ... or one absolute end time for every case
    stop_timeout = 10.0                # seconds from SIGTERM/SIGINT to a checkpointed exit

    [sweep]                            # the full grid over these, in this order
    shear_rate = [40, 80, 160]                     # explicit values
    psi_bar = { linspace = [0.3, 0.7, 3] }         # start, stop, number (numpy.linspace)
    excess_length = { logspace = [0.1, 2.3, 4] }   # start, stop, number, geometric (numpy.geomspace)
    B2 = 0.3                                       # a single value

    [analysis]                         # optional: thresholds of hpcves analyze (regimes.AnalysisSettings)
    min_cycles = 3

Sweepable: ``shear_rate``, ``psi_bar``, ``excess_length``, ``B2`` (physics).
Cases are numbered in grid order (the last swept key varies fastest); the id
is the zero-padded number. Every case is built -- and so validated -- before
any work starts; an error names the case and its swept values.

A ``[search]`` table makes it a critical-shear search (search.py, docs/analysis.md)::

    [search]
    low = 10.0          # the range of S searched for S_C
    high = 320.0
    rel_tol = 0.02      # stop when the bracket [S_TT, S_PT] is this narrow
    max_cases = 16      # per search
    points = 1          # shear rates per search and stage (1: bisection)
    along = "shear_rate"    # or "viscosity_ratio": low and high are then lambda's range, for lambda_C

Then ``[sweep]`` may hold only ``psi_bar``, ``excess_length`` and ``B2`` (and ``shear_rate`` in a search
along lambda): one search per point of that grid. The cases are made stage by stage as the
searches ask for them (numbered in that order); the ends of every search's
range are validated up front.

A ``[refine]`` table makes it a refinement of the regime boundaries over two
swept parameters (refine.py, docs/analysis.md)::

    [refine]
    axes = ["shear_rate", "psi_bar"]                  # default: the first two swept keys
    tolerance = { shear_rate = 0.1, psi_bar = 0.05 }  # relative on S and lambda, absolute on the others
    max_cases = 150                                   # per refinement
    straight_span = 4                                 # along a boundary, cells up to 4 tolerances wide
    max_N = 256                                       # an under-resolved case runs again at 2 N, up to 256

The ``[sweep]`` values of the two axes are the coarse grid; every combination
of the other swept keys is a refinement of its own. Cases are made stage by
stage as the refinements ask for them; every point of the coarse grids is
validated up front.

A ``[starts]`` table runs every point from several starts (docs/analysis.md)::

    [starts]                                  # name = the start's physics keys (START_KEYS)
    ellipse = {}                              # the base case's start
    smoothed = { initial_shape = "smoothed", psi_init_coordinate = "ellipse_parameter" }
    one_domain = { initial_phase = "domains", phase_domains = 1, delta = 0.16 }

It is swept like a parameter, as the last key (``start``: 0, 1, ... in the order
given; the file's index holds the number, its tables the name). With ``[refine]``
every start is a refinement of its own; with ``[search]`` a search of its own.

A ``[chain]`` table makes a grid study a continuation (docs/analysis.md)::

    [chain]
    along = "shear_rate"   # a swept key: its values in [sweep] order make a chain for every combination
                           # of the other swept keys
    back = true            # then back through the same values (hysteresis); default false

The first case of a chain starts as the base case says; every other case from the
end state of the case before it (continuation.carried_start: the shape rescaled to
its excess length, psi shifted to its psi_bar), so it runs only once that case has
finished. Cases are numbered chain by chain, each chain in its order.
"""
from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hpcves.analysis.refine import CREEP_TIGHTENING, RTOL_TIGHTENING, RefinePlan, RefineSettings
from hpcves.analysis.regimes import AnalysisSettings
from hpcves.analysis.search import SearchSettings
from hpcves.config import Problems, case_from_dict, check_type, clean_number, read_settings, refuse_unknown, with_prefix
from hpcves.model.params import SWEEPABLE, Case, ConfigError, Numerics  # SWEEPABLE: what [sweep] varies
from hpcves.run.resolution import expected_N

SEARCHABLE = ("psi_bar", "excess_length", "B2")      # a search runs along the shear rate for each of these


def search_keys(along: str = "shear_rate") -> tuple:
    """The keys a search's ``[sweep]`` may hold (one search per point of it) and its tables' columns:
    SEARCHABLE, and the shear rate where the search runs along lambda."""
    return SEARCHABLE if along == "shear_rate" else SEARCHABLE + ("shear_rate",)
#: what a named start of ``[starts]`` may set: the physics of the initial shape and phase
START_KEYS = ("initial_shape", "psi_init_coordinate", "initial_phase", "phase_domains", "phase_center",
              "phase_seed", "delta", "stored_file", "stored_case", "stored_time")
#: the longest wait from a stop request to a checkpointed exit: a day (time.sleep overflows near 1e308,
#: and a batch system's warning comes minutes, not days, before the kill)
MAX_STOP_TIMEOUT = 86400.0
CAMPAIGN_KEYS = ("name", "output", "t_end", "shear_times", "t_end_min", "samples_per_shear_time", "stop_timeout")
#: more cases than this in one study is surely a mistake (checked before any case is built: building
#: and validating 10^5 cases takes ~6 s; 10^6 took 60 s and 680 MB)
MAX_CASES = 100_000


@dataclass(frozen=True)
class StudyCase:
    """One case of a study: its id, the full parameters and the swept values."""

    case_id: str
    case: Case
    swept: dict                    # {"shear_rate": 80.0, ...} in sweep order
    search: int = -1               # search (refine) studies: which search (refinement) the case belongs to
    after: str = ""                # chain studies: the case whose end state this one starts from ("": none)

    @property
    def cost(self) -> float:
        """Relative cost: steps x N^2 (the dense Stokeslet work of a step; N where N adapts: the grid
        its start needs)."""
        return self.case.estimated_steps * expected_N(self.case) ** 2

    def label(self) -> str:
        return ", ".join(f"{k} = {v:g}" for k, v in self.swept.items())


@dataclass(frozen=True)
class Study:
    """A campaign: name, output file, and its cases (all validated).

    A grid study knows every case up front. A search study (``search`` set)
    has one critical-shear search per point of its sweep (``searches``) and
    gains its cases stage by stage (:meth:`search_case`, :meth:`with_cases`).
    """

    name: str
    output: Path
    sweep: dict                    # key -> tuple of values
    cases: tuple                   # StudyCase, in id order
    stop_timeout: float = 10.0
    source: str = ""               # the campaign file's text (kept in the HDF5 file)
    analysis: AnalysisSettings = AnalysisSettings()   # thresholds of hpcves analyze ([analysis])
    base: Case | None = None       # the base case (swept values, t_end and sampling replaced per case)
    times: TimeRules = field(default_factory=lambda: TimeRules())
    search: SearchSettings | None = None
    searches: tuple = ()           # search studies: the swept values of each search, in sweep order
    refine: RefinePlan | None = None
    refinements: tuple = ()        # refine studies: the values of the other swept keys of each refinement
    chain: ChainPlan | None = None  # a continuation: cases start from the end of the one before
    starts: tuple = ()             # ((name, {physics key: value}), ...) of [starts]; swept as "start"

    @property
    def mode(self) -> str:
        """"grid" (every case known up front), "search" or "refine" (cases added stage by stage)."""
        return "search" if self.search else "refine" if self.refine else "grid"

    @property
    def staged(self) -> bool:
        """Whether the study gains its cases stage by stage (a search or a refinement)."""
        return self.mode != "grid"

    @property
    def refine_settings(self) -> RefineSettings:
        """The plane, tolerances and budget shared by every refinement of a refine study."""
        return self.refine.settings(self.sweep)

    @property
    def fingerprint(self) -> str:
        """SHA-256 of the expanded study (name, ids, every parameter of every case).

        Comments and formatting of the TOML do not change it; any parameter does.
        A search study's cases are not known up front: its fingerprint covers
        what decides them -- base case, time rules, sweep, search range and
        the classification thresholds (which decide where the search goes next).
        A grid study's covers the thresholds when its cases run until decided. A refine study's leaves
        out its budget (max_cases): raised, it continues the refinement where it stopped; and
        min_resize_tail and min_rtol: lowered, its creeping or unsettled points run again (the cases run so
        far stay what they are).
        """
        if self.refine is not None:
            plan = {k: v for k, v in dataclasses.asdict(self.refine).items()
                    if k not in ("max_cases", "min_resize_tail", "min_rtol")}
            if plan["straight_span"] == 1:   # the quadtree: as files made before the key existed
                del plan["straight_span"]
            if not plan["max_N"]:            # no retries: as files made before the key existed
                del plan["max_N"]
            if not plan["attractors"]:       # one start a refinement: as files made before the key existed
                del plan["attractors"]
            payload = {"name": self.name, "mode": "refine", "base": self.base.significant(),
                       "end_time": dataclasses.asdict(self.times), "sweep": {k: list(v) for k, v in self.sweep.items()},
                       "refine": plan, "analysis": dataclasses.asdict(self.analysis)}
            if self.starts:
                payload["starts"] = [list(s) for s in self.starts]
        elif self.search is None:
            payload = {"name": self.name,
                       "cases": [[c.case_id, c.case.significant()] + ([c.after] if self.chain else [])
                                 for c in self.cases]}
            if self.base.run.until_decided:          # the thresholds decide when its cases stop
                payload["analysis"] = dataclasses.asdict(self.analysis)
        else:
            times = dataclasses.asdict(self.times)
            samples = times.pop("samples_per_shear_time")
            search = dataclasses.asdict(self.search)
            if search["along"] == "shear_rate":    # as files made before the key existed
                del search["along"]
            payload = {"name": self.name, "mode": "search", "base": self.base.significant(),
                       "end_time": times, "searches": list(self.searches),
                       "search": search, "analysis": dataclasses.asdict(self.analysis)}
            if samples is not None:        # absent from files written before the rule existed
                payload["samples_per_shear_time"] = samples
            if self.starts:
                payload["starts"] = [list(s) for s in self.starts]
        return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()

    def by_id(self, case_id: str) -> StudyCase:
        return self.cases[int(case_id)]

    @property
    def point_starts(self) -> tuple:
        """The starts every point of a refinement of attractors runs from (0., 1., ...); (None,) else."""
        return self.sweep["start"] if self.refine and self.refine.attractors else (None,)

    @property
    def most_cases(self) -> int:
        """Every case the study can have: the grid, or max_cases for every search or refinement."""
        if self.refine:
            return len(self.refinements) * self.refine.max_cases
        if self.chain:
            return sum(1 for _ in self.chain.links(self.sweep))
        points = math.prod(len(v) for v in self.sweep.values())
        return points * (self.search.max_cases if self.search else 1)

    @property
    def id_width(self) -> int:
        """Digits of a case id: enough for every case the study can have."""
        return max(4, len(str(self.most_cases - 1)))

    def make_case(self, case_id: str, swept: dict, search: int = -1, numerics: dict | None = None,
                  after: str = "") -> StudyCase:
        """The base case with ``swept`` values and the time rules (t_end, sampling) applied (validated);
        ``numerics``: values that replace the base case's (a refinement's run again: a larger N or N_max,
        a tighter resize_tail); ``after``: the case whose end state it starts from (a chain)."""
        where = f"case {case_id}" + (f" ({', '.join(f'{k} = {v:g}' for k, v in swept.items())})" if swept else "")
        try:
            values = {k: v for k, v in swept.items() if k != "start"}
            if "start" in swept:
                values.update(self.starts[int(swept["start"])][1])
            physics = dataclasses.replace(self.base.physics, **values)
            S, run = physics.shear_rate, self.base.run
            run = dataclasses.replace(run, t_end=self.times.end_time(S, run.t_end),
                                      sample_interval=self.times.sample_interval(S, run.sample_interval,
                                                                                 self.base.numerics.fixed_dt))
            case = Case(physics=physics, numerics=dataclasses.replace(self.base.numerics, **(numerics or {})),
                        run=run)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        return StudyCase(case_id, case, swept, search, after)

    def search_case(self, search: int, value: float, case_id: str) -> StudyCase:
        """Case ``case_id`` of search number ``search``, at ``value`` of what it runs along (the shear rate
        unless [search] along says otherwise)."""
        return self.make_case(case_id, {self.search.along: value, **self.searches[search]}, search)

    def refine_case(self, refinement: int, x: float, y: float, case_id: str, numerics: dict | None = None,
                    start: float | None = None) -> StudyCase:
        """Case ``case_id`` of refinement number ``refinement``, at the point (x, y) of its plane;
        ``numerics``: the point's run again (:meth:`retry_numerics`); ``start``: which of [starts] (a
        refinement of attractors runs every point from each)."""
        x_key, y_key = self.refine.axes
        fixed = self.refinements[refinement] if start is None else {**self.refinements[refinement], "start": start}
        swept = {k: x if k == x_key else y if k == y_key else fixed[k] for k in self.sweep}
        return self.make_case(case_id, swept, refinement, numerics)

    def retry_numerics(self, numerics: Numerics, unresolved: bool, crept: bool, unsettled: bool = False) -> dict | None:
        """What a refinement point's next run changes after a run with ``numerics`` that stopped as
        under-resolved (N, or N_max where N adapts, doubled: RefineSettings.retry_N), crept where N adapts
        (resize_tail tightened: RefineSettings.retry_tail) or stayed unsettled with an adaptive step (rtol
        tightened: RefineSettings.retry_rtol); None: it runs no more. The run again keeps what the run
        before changed."""
        settings = self.refine_settings
        key = "N_max" if numerics.adaptive_N else "N"
        kept = {key: getattr(numerics, key), "resize_tail": numerics.resize_tail,
                **({"rtol": numerics.rtol} if numerics.adaptive else {})}
        if unresolved:
            N = settings.retry_N(getattr(numerics, key))
            return None if N is None else {**kept, key: N}
        if crept and numerics.adaptive_N:
            tail = settings.retry_tail(numerics.resize_tail)
            return None if tail is None else {**kept, "resize_tail": tail}
        if unsettled and numerics.adaptive:
            rtol = settings.retry_rtol(numerics.rtol)
            return None if rtol is None else {**kept, "rtol": rtol}
        return None

    def with_cases(self, new) -> "Study":
        """This study with ``new`` cases appended (their ids must continue the numbering)."""
        new = tuple(new)
        for i, c in enumerate(new, start=len(self.cases)):
            if int(c.case_id) != i:
                raise ValueError(f"case id {c.case_id} does not follow {i - 1}")
        return dataclasses.replace(self, cases=self.cases + new)

    @property
    def sweep_keys(self) -> tuple:
        """The per-case swept keys (a search adds what it runs along in front: the shear rate unless said)."""
        return ((self.search.along,) if self.search else ()) + tuple(self.sweep)


def sweep_values(key: str, spec) -> tuple:
    """The values of one swept parameter from a number, a list, or {linspace|logspace = [a, b, n]};
    each value once (a value given twice would run the same cases twice)."""
    values = _sweep_values(key, spec)
    seen = {}
    for value in values:
        seen[clean_number(value)] = seen.get(clean_number(value), 0) + 1
    repeated = [f"{v:g} ({n} times)" for v, n in seen.items() if n > 1]
    if repeated:
        raise ConfigError(f"sweep.{key}: {', '.join(repeated)}: every value must be different "
                          "(a repeated value runs the same cases twice)")
    return values


def _sweep_values(key: str, spec) -> tuple:
    where = f"sweep.{key}"
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        return (float(spec),)
    if isinstance(spec, list):
        if not spec:
            raise ConfigError(f"{where}: empty list")
        if len(spec) > MAX_CASES:
            raise ConfigError(f"{where}: {len(spec)} values; more than {MAX_CASES} is surely a mistake")
        return tuple(check_type(f"{where}[{i}]", v, float) for i, v in enumerate(spec))
    if isinstance(spec, dict):
        if len(spec) != 1 or next(iter(spec)) not in ("linspace", "logspace"):
            raise ConfigError(f"{where} = {spec!r}: use a list, a number, "
                              "{ linspace = [start, stop, num] } or { logspace = [start, stop, num] }")
        kind, args = next(iter(spec.items()))
        if not isinstance(args, list) or len(args) != 3:
            raise ConfigError(f"{where}.{kind} = {args!r}: must be [start, stop, num]")
        start = check_type(f"{where}.{kind} start", args[0], float)
        stop = check_type(f"{where}.{kind} stop", args[1], float)
        num = check_type(f"{where}.{kind} num", args[2], int)
        if not 1 <= num <= MAX_CASES:
            raise ConfigError(f"{where}.{kind}: num = {num} must lie in [1, {MAX_CASES}]")
        if kind == "logspace":
            if start <= 0 or stop <= 0:
                raise ConfigError(f"{where}.logspace: start and stop must be > 0 (they are values, "
                                  "spaced geometrically), got {start}, {stop}")
            values = np.geomspace(start, stop, num)
        else:
            values = np.linspace(start, stop, num)
        return tuple(clean_number(v) for v in values)
    raise ConfigError(f"{where} = {spec!r}: must be a number, a list or a linspace/logspace table")


def study_from_toml(text: str, source: str = "<string>", default_name: str = "campaign") -> Study:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML ({exc})") from None
    try:
        return _study_from_dict(data, default_name, text)
    except ConfigError as exc:
        raise with_prefix(f"{source}: ", exc) from None


def load_study(path: str | Path) -> Study:
    """Read a campaign file and build (validate) every case."""
    text = read_settings(path, "[campaign], [sweep] or a case's tables")
    return study_from_toml(text, source=str(Path(path)), default_name=Path(path).stem)


def _study_from_dict(data: dict, default_name: str, text: str) -> Study:
    data = dict(data)
    is_search, is_refine = "search" in data, "refine" in data
    if is_search and is_refine:
        raise ConfigError("[search] and [refine] are two kinds of campaign: give one")
    is_chain = "chain" in data
    has_starts = "starts" in data
    tables = {t: data.pop(t, {}) for t in ("campaign", "sweep", "analysis", "search", "refine", "chain", "starts")}
    for table, value in tables.items():
        if not isinstance(value, dict):
            raise ConfigError(f"[{table}] must be a table")
    campaign, sweep_spec = tables["campaign"], tables["sweep"]
    problems = Problems()              # the tables are independent: every problem of them at once
    with problems.check():
        refuse_unknown(campaign, CAMPAIGN_KEYS, "[campaign]")
    base, sweep = None, {}
    with problems.check("base case: "):
        base = case_from_dict(data)
    name = campaign.get("name", default_name)
    with problems.check():
        if not isinstance(name, str) or not name.strip():
            raise ConfigError(f"campaign.name = {name!r}: must be a non-empty string")
        if len(name) > 200:
            raise ConfigError(f"campaign.name = {name[:20]!r}...: {len(name)} characters, at most 200 (the name "
                              "is the default file name, which file systems limit to 255 bytes)")
        if "/" in name or "\\" in name or not name.isprintable() or name != name.strip():
            # the name becomes the default file name, the batch job's name and a title
            raise ConfigError(f"campaign.name = {name!r}: letters, digits and punctuation without '/' or '\\', "
                              "no line breaks or other control characters, no spaces at either end")
    output = campaign.get("output", f"{name}.h5")
    with problems.check():
        if not isinstance(output, str) or not output:
            raise ConfigError(f"campaign.output = {output!r}: must be a file path")
        if "output" in campaign and (not output.isprintable() or output.endswith("/")):
            raise ConfigError(f"campaign.output = {output!r}: must be a file path (no control characters, "
                              "not ending in '/')")
    with problems.check():
        stop_timeout = check_type("campaign.stop_timeout", campaign.get("stop_timeout", 10.0), float)
        if not 0 < stop_timeout <= MAX_STOP_TIMEOUT:
            raise ConfigError(f"campaign.stop_timeout = {stop_timeout}: must be > 0 seconds"
                              + (f" and at most {MAX_STOP_TIMEOUT:g} (a day)" if stop_timeout > 0 else ""))
    with problems.check():
        times = TimeRules.from_campaign(campaign)
    with problems.check():
        analysis = AnalysisSettings.from_dict(tables["analysis"])
    with problems.check():
        search = SearchSettings.from_dict(tables["search"]) if is_search else None
    with problems.check():
        along = tables["search"].get("along", "shear_rate") if is_search else None
        allowed = search_keys(along) if is_search else SWEEPABLE
        unknown = [k for k in sweep_spec if k not in allowed]
        if unknown:
            if "start" in unknown:
                raise ConfigError("sweep over start: name the starts in a [starts] table instead "
                                  "(name = { initial_shape = ..., ... }); they are swept as the last key")
            if is_search and unknown == [along]:
                raise ConfigError(f"[search] runs along {along}: leave {along} out of [sweep] "
                                  "(the search range is [search] low and high)")
            raise ConfigError(f"sweep over {', '.join(unknown)}: only {', '.join(allowed)} can be swept")
        sweep = {}
        for key, spec in sweep_spec.items():
            with problems.check():
                sweep[key] = sweep_values(key, spec)
    starts = ()
    with problems.check():
        if has_starts and not tables["starts"]:
            raise ConfigError("[starts] names no start: give each one as name = { initial_shape = ..., ... } "
                              "(or leave the table out: one start, the base case's)")
        starts = start_table(tables["starts"], base) if base is not None else ()
        if starts:
            sweep["start"] = tuple(float(i) for i in range(len(starts)))
    chain = None
    if is_chain:
        with problems.check():
            chain = ChainPlan.from_dict(tables["chain"], sweep, staged=is_search or is_refine)
    problems.raise_any()
    if is_refine and "start" in (tables["refine"].get("axes") or ()):
        raise ConfigError("[refine]: the starts are not an axis of a plane; every start is a refinement of its own")
    refine = RefinePlan.from_dict(tables["refine"], sweep) if is_refine else None
    if refine is not None and refine.max_N and base.numerics.adaptive_N:
        if refine.max_N < 2 * base.numerics.N_max:
            raise ConfigError(f"[refine]: max_N = {refine.max_N}: with numerics.N = \"auto\" a case that N_max = "
                              f"{base.numerics.N_max} leaves under-resolved runs again with N_max doubled, so max_N "
                              f"must be at least {2 * base.numerics.N_max} (0: never)")
    elif refine is not None and refine.max_N and refine.max_N < 2 * base.numerics.N:
        raise ConfigError(f"[refine]: max_N = {refine.max_N}: an under-resolved case runs again at twice its "
                          f"N = {base.numerics.N}, so max_N must be at least {2 * base.numerics.N} (0: never)")
    if refine is not None and refine.min_resize_tail:
        if not base.numerics.adaptive_N:
            raise ConfigError(f"[refine]: min_resize_tail = {refine.min_resize_tail:g} runs a creeping case again "
                              "with a tighter numerics.resize_tail, which only a run with numerics.N = \"auto\" has "
                              "(with a fixed N, max_N runs an under-resolved case again at 2 N)")
        first = base.numerics.resize_tail / CREEP_TIGHTENING
        if refine.min_resize_tail > first * (1 + 1e-9):
            raise ConfigError(f"[refine]: min_resize_tail = {refine.min_resize_tail:g}: a creeping case runs again "
                              f"with numerics.resize_tail / {CREEP_TIGHTENING:g} = {first:g}, below it, so none "
                              f"would; give at most {first:g} (0: never)")
    if refine is not None and refine.min_rtol:
        if not base.numerics.adaptive:
            raise ConfigError(f"[refine]: min_rtol = {refine.min_rtol:g} runs an unsettled case again with a tighter "
                              "numerics.rtol, which only an adaptive step has (give numerics.rtol)")
        first = base.numerics.rtol / RTOL_TIGHTENING
        if refine.min_rtol > first * (1 + 1e-9):
            raise ConfigError(f"[refine]: min_rtol = {refine.min_rtol:g}: an unsettled case runs again with "
                              f"numerics.rtol / {RTOL_TIGHTENING:g} = {first:g}, below it, so none would; give at "
                              f"most {first:g} (0: never)")
    if refine is not None and refine.attractors:
        if not starts or len(starts) < 2:
            raise ConfigError("[refine]: attractors = true runs every point from every start: name at least two "
                              "in a [starts] table")
        coarse = len(sweep[refine.axes[0]]) * len(sweep[refine.axes[1]]) * len(starts)
        if refine.max_cases < coarse:
            raise ConfigError(f"[refine]: max_cases = {refine.max_cases}: fewer than the {coarse} cases of the coarse "
                              f"grid from {len(starts)} starts")
    others = [k for k in sweep if refine and k not in refine.axes and not (refine.attractors and k == "start")]
    refinements = tuple(dict(zip(others, values)) for values in itertools.product(*(sweep[k] for k in others)))
    study = Study(name=name, output=Path(output), sweep=sweep, cases=(), stop_timeout=stop_timeout, source=text,
                  analysis=analysis, base=base, times=times, search=search, refine=refine,
                  refinements=refinements if refine else (), chain=chain, starts=starts)
    if study.most_cases > MAX_CASES:
        raise ConfigError(f"the sweep has {study.most_cases} cases; more than {MAX_CASES} is surely a mistake")
    if refine is not None:          # validate every point of every coarse grid
        for i in range(len(refinements)):
            for x in sweep[refine.axes[0]]:
                for y in sweep[refine.axes[1]]:
                    for start in study.point_starts:
                        study.refine_case(i, x, y, f"of refinement {i}", start=start)
        return study
    if chain is not None:
        width = study.id_width
        return study.with_cases(study.make_case(f"{i:0{width}d}", swept, after=f"{i - 1:0{width}d}" if linked else "")
                                for i, (swept, linked) in enumerate(chain.links(sweep)))
    points = [dict(zip(sweep, values)) for values in itertools.product(*sweep.values())]
    if search is None:
        width = study.id_width
        return study.with_cases(study.make_case(f"{i:0{width}d}", swept) for i, swept in enumerate(points))
    study = dataclasses.replace(study, searches=tuple(points))
    for i in range(len(points)):         # validate every search at both ends of its range
        for value in (search.low, search.high):
            study.search_case(i, value, f"of search {i}")
    return study


@dataclass(frozen=True)
class TimeRules:
    """Per-case times from the shear rate S ([campaign] keys).

    t_end: ``max(t_end, t_end_min)``, or ``max(shear_times / S, t_end_min)``, or
    the base case's t_end (at least t_end_min). The sampling interval of the
    time series: the base case's, or -- with ``samples_per_shear_time`` = k --
    ``min(base, 1 / (k S))`` (but at least dt), so that fast motion (a phase-treading period
    is ~7 shear times) is sampled as finely at S = 320 as at S = 20.
    """

    t_end: float | None = None
    shear_times: float | None = None
    t_end_min: float = 0.0
    samples_per_shear_time: float | None = None

    def end_time(self, shear_rate: float, base: float) -> float:
        if self.t_end is not None:
            return max(self.t_end, self.t_end_min)
        if self.shear_times is not None:
            if shear_rate == 0:
                if self.t_end_min > 0:
                    return self.t_end_min
                raise ConfigError("shear_rate = 0 has no shear time: set campaign.t_end_min")
            return clean_number(max(self.shear_times / shear_rate, self.t_end_min))
        return max(base, self.t_end_min)

    def sample_interval(self, shear_rate: float, base: float, dt: float) -> float:
        if self.samples_per_shear_time is None or shear_rate == 0:
            return base
        return clean_number(max(dt, min(base, 1.0 / (self.samples_per_shear_time * shear_rate))))

    @classmethod
    def from_campaign(cls, campaign: dict) -> "TimeRules":
        absolute = campaign.get("t_end")
        shear_times = campaign.get("shear_times")
        if absolute is not None and shear_times is not None:
            raise ConfigError("campaign: give t_end or shear_times, not both")
        floor = check_type("campaign.t_end_min", campaign.get("t_end_min", 0.0), float)
        if floor < 0:
            raise ConfigError(f"campaign.t_end_min = {floor}: must be >= 0")
        if absolute is not None:
            absolute = check_type("campaign.t_end", absolute, float)
            if not absolute > 0:
                raise ConfigError(f"campaign.t_end = {absolute}: must be > 0")
        if shear_times is not None:
            shear_times = check_type("campaign.shear_times", shear_times, float)
            if not shear_times > 0:
                raise ConfigError(f"campaign.shear_times = {shear_times}: must be > 0")
        samples = campaign.get("samples_per_shear_time")
        if samples is not None:
            samples = check_type("campaign.samples_per_shear_time", samples, float)
            if not 0 < samples <= 1e4:
                raise ConfigError(f"campaign.samples_per_shear_time = {samples:g}: must be > 0 and at most 1e4 "
                                  "(a sample every 1e-4 shear times)")
        return cls(absolute, shear_times, floor, samples)


@dataclass(frozen=True)
class ChainPlan:
    """``[chain]`` of a campaign file: continuation along one swept key (see the module's docstring)."""

    along: str
    back: bool = False

    @classmethod
    def from_dict(cls, values: dict, sweep: dict, staged: bool = False) -> "ChainPlan":
        refuse_unknown(values, ("along", "back"), "[chain]")
        if staged:
            raise ConfigError("[chain] runs a grid of continuations: it cannot be combined with [search] "
                              "or [refine]")
        along = values.get("along")
        if along == "start":
            raise ConfigError("chain.along = 'start': a chain runs along a parameter; every start begins "
                              "chains of its own")
        if not isinstance(along, str) or along not in sweep:
            raise ConfigError(f"chain.along = {along!r}: must name a swept key "
                              f"({', '.join(sweep) or 'nothing is swept'})")
        if len(sweep[along]) < 2:
            raise ConfigError(f"chain.along = {along!r}: sweeps one value; a chain needs at least two")
        back = values.get("back", False)
        if not isinstance(back, bool):
            raise ConfigError(f"chain.back = {back!r}: must be true or false")
        return cls(along, back)

    def values(self, sweep: dict) -> tuple:
        """The values of the chained key in the order a chain visits them (there and, with back, back)."""
        forth = tuple(sweep[self.along])
        return forth + (forth[-2::-1] if self.back else ())

    def links(self, sweep: dict):
        """(swept values, starts from the case before) of every case, chain by chain."""
        others = [k for k in sweep if k != self.along]
        for fixed in itertools.product(*(sweep[k] for k in others)):
            point = dict(zip(others, fixed))
            for j, value in enumerate(self.values(sweep)):
                yield {k: value if k == self.along else point[k] for k in sweep}, j > 0


#: what a start's name may be
START_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,63}")


def start_table(table: dict, base: Case) -> tuple:
    """((name, {key: value}), ...) of a ``[starts]`` table, each start validated on the base case."""
    if not table:
        return ()
    starts = []
    for name, values in table.items():
        if not START_NAME.fullmatch(name):
            # a start's name labels tables, figures and file names (regimes.csv, case pages)
            raise ConfigError(f"[starts]: the name {name!r}: letters, digits, '_', '-', '.' and '+' only, "
                              "beginning with a letter or digit (it labels tables, figures and file names)")
        where = f"starts.{name}"
        if not isinstance(values, dict):
            raise ConfigError(f"{where} = {values!r}: must be a table of {', '.join(START_KEYS)} (or {{}})")
        refuse_unknown(values, START_KEYS, where)
        try:
            dataclasses.replace(base.physics, **values)
        except (ConfigError, TypeError) as exc:
            raise ConfigError(f"{where}: {exc}") from None
        starts.append((name, dict(values)))
    return tuple(starts)
