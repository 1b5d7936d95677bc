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
"""
from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .config import case_from_dict, check_type, read_text
from .params import Case, ConfigError
from .regimes import AnalysisSettings

SWEEPABLE = ("shear_rate", "psi_bar", "excess_length", "B2")
CAMPAIGN_KEYS = ("name", "output", "t_end", "shear_times", "t_end_min", "stop_timeout")
MAX_CASES = 1_000_000


@dataclass(frozen=True)
class StudyCase:
    """One case of a study: its id, the full parameters and the swept values."""

    case_id: str
    case: Case
    swept: dict                    # {"shear_rate": 80.0, ...} in sweep order

    @property
    def cost(self) -> float:
        """Relative cost: steps x N^2 (the dense Stokeslet work of a step)."""
        return float(self.case.n_steps) * self.case.numerics.N ** 2

    def label(self) -> str:
        return ", ".join(f"{k} = {v:g}" for k, v in self.swept.items())


@dataclass(frozen=True)
class Study:
    """A campaign: name, output file, and its cases (all validated)."""

    name: str
    output: Path
    sweep: dict                    # key -> tuple of values
    cases: tuple                   # StudyCase, in id order
    stop_timeout: float = 10.0
    source: str = ""               # the campaign file's text (kept in the HDF5 file)
    analysis: AnalysisSettings = AnalysisSettings()   # thresholds of hpcves analyze ([analysis])

    @property
    def fingerprint(self) -> str:
        """SHA-256 of the expanded study (name, ids, every parameter of every case).

        Comments and formatting of the TOML do not change it; any parameter does.
        """
        payload = {"name": self.name,
                   "cases": [[c.case_id, c.case.to_dict()] for c in self.cases]}
        return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()

    def by_id(self, case_id: str) -> StudyCase:
        return self.cases[int(case_id)]


def _round(value: float) -> float:
    """12 significant digits: 0.30000000000000004 -> 0.3 (values are recorded, so keep them clean)."""
    return float(f"{value:.12g}")


def sweep_values(key: str, spec) -> tuple:
    """The values of one swept parameter from a number, a list, or {linspace|logspace = [a, b, n]}."""
    where = f"sweep.{key}"
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        return (float(spec),)
    if isinstance(spec, list):
        if not spec:
            raise ConfigError(f"{where}: empty list")
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
        if num < 1:
            raise ConfigError(f"{where}.{kind}: num = {num} must be >= 1")
        if kind == "logspace":
            if start <= 0 or stop <= 0:
                raise ConfigError(f"{where}.logspace: start and stop must be > 0 (they are values, "
                                  "spaced geometrically), got {start}, {stop}")
            values = np.geomspace(start, stop, num)
        else:
            values = np.linspace(start, stop, num)
        return tuple(_round(v) for v in values)
    raise ConfigError(f"{where} = {spec!r}: must be a number, a list or a linspace/logspace table")


def study_from_toml(text: str, source: str = "<string>", default_name: str = "campaign") -> Study:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML ({exc})") from None
    try:
        return _study_from_dict(data, default_name, text)
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None


def load_study(path: str | Path) -> Study:
    """Read a campaign file and build (validate) every case."""
    path = Path(path)
    return study_from_toml(read_text(path), source=str(path), default_name=path.stem)


def _study_from_dict(data: dict, default_name: str, text: str) -> Study:
    data = dict(data)
    campaign = data.pop("campaign", {})
    sweep_spec = data.pop("sweep", {})
    analysis_spec = data.pop("analysis", {})
    for table, value in (("campaign", campaign), ("sweep", sweep_spec), ("analysis", analysis_spec)):
        if not isinstance(value, dict):
            raise ConfigError(f"[{table}] must be a table")
    unknown = sorted(set(campaign) - set(CAMPAIGN_KEYS))
    if unknown:
        raise ConfigError(f"unknown key{'s' if len(unknown) > 1 else ''} in [campaign]: {', '.join(unknown)} "
                          f"(known: {', '.join(CAMPAIGN_KEYS)})")
    try:
        base = case_from_dict(data)
    except ConfigError as exc:
        raise ConfigError(f"base case: {exc}") from None

    name = campaign.get("name", default_name)
    if not isinstance(name, str) or not name.strip():
        raise ConfigError(f"campaign.name = {name!r}: must be a non-empty string")
    output = campaign.get("output", f"{name}.h5")
    if not isinstance(output, str) or not output:
        raise ConfigError(f"campaign.output = {output!r}: must be a file path")
    stop_timeout = check_type("campaign.stop_timeout", campaign.get("stop_timeout", 10.0), float)
    if not stop_timeout > 0:
        raise ConfigError(f"campaign.stop_timeout = {stop_timeout}: must be > 0 seconds")
    end_time = _end_time_rule(campaign)
    analysis = AnalysisSettings.from_dict(analysis_spec)

    unknown = [k for k in sweep_spec if k not in SWEEPABLE]
    if unknown:
        raise ConfigError(f"sweep over {', '.join(unknown)}: only {', '.join(SWEEPABLE)} can be swept")
    sweep = {key: sweep_values(key, spec) for key, spec in sweep_spec.items()}
    n_cases = math.prod(len(v) for v in sweep.values())
    if n_cases > MAX_CASES:
        raise ConfigError(f"the sweep has {n_cases} cases; more than {MAX_CASES} is surely a mistake")
    width = max(4, len(str(n_cases - 1)))

    cases = []
    for index, values in enumerate(itertools.product(*sweep.values())):
        swept = dict(zip(sweep, values))
        case_id = f"{index:0{width}d}"
        where = f"case {case_id}" + (f" ({', '.join(f'{k} = {v:g}' for k, v in swept.items())})" if swept else "")
        try:
            physics = dataclasses.replace(base.physics, **swept)
            run = dataclasses.replace(base.run, t_end=end_time(physics.shear_rate, base.run.t_end))
            case = Case(physics=physics, numerics=base.numerics, run=run)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        cases.append(StudyCase(case_id, case, swept))
    return Study(name=name, output=Path(output), sweep=sweep, cases=tuple(cases),
                 stop_timeout=stop_timeout, source=text, analysis=analysis)


def _end_time_rule(campaign: dict):
    """t_end as a function of the shear rate (and the base case's t_end)."""
    absolute = campaign.get("t_end")
    shear_times = campaign.get("shear_times")
    if absolute is not None and shear_times is not None:
        raise ConfigError("campaign: give t_end or shear_times, not both")
    floor = check_type("campaign.t_end_min", campaign.get("t_end_min", 0.0), float)
    if floor < 0:
        raise ConfigError(f"campaign.t_end_min = {floor}: must be >= 0")
    if absolute is not None:
        value = check_type("campaign.t_end", absolute, float)
        if not value > 0:
            raise ConfigError(f"campaign.t_end = {value}: must be > 0")
        return lambda shear_rate, base: max(value, floor)
    if shear_times is not None:
        n = check_type("campaign.shear_times", shear_times, float)
        if not n > 0:
            raise ConfigError(f"campaign.shear_times = {n}: must be > 0")

        def by_shear(shear_rate, base):
            if shear_rate == 0:
                if floor > 0:
                    return floor
                raise ConfigError("shear_rate = 0 has no shear time: set campaign.t_end_min")
            return _round(max(n / shear_rate, floor))
        return by_shear
    return lambda shear_rate, base: max(base, floor)
