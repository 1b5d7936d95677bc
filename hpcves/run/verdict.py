"""The verdict on one stored case: its data read from the case store, then classified.

One row of regimes.csv per case (:data:`hpcves.reports.analyze.COLUMNS`): the regime by
:func:`hpcves.analysis.regimes.classify`, with the discretisation error bars of
:mod:`hpcves.analysis.accuracy`; a failed, damaged or model-limit case gets its reason instead.
Used by ``hpcves analyze`` and by the stage drivers of searches and refinements.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, fields, replace

import numpy as np

from hpcves.analysis import accuracy
from hpcves.analysis.pattern import common_topology
from hpcves.analysis.regimes import CREEPING, UNDECIDED, UNSETTLED, AnalysisSettings, Classification, classify
from hpcves.analysis.regimes import FAILED as FAILED_OUTCOME
from hpcves.analysis.regimes import MODEL_LIMIT as MODEL_LIMIT_OUTCOME
from hpcves.analysis.stress import SettledMean, settled_mean
from hpcves.model.params import SWEEPABLE as PARAMETERS  # the columns of a case's parameters in a row
from hpcves.model.params import parameter_of
from hpcves.run.decision import REGIMES_BY_CODE
from hpcves.run.runner import MODEL_LIMIT_PREFIX, UNDER_RESOLVED
from hpcves.run.store import FAILED, FINISHED, MODEL_LIMIT, STATUS_NAMES, CaseStore

#: the status of a campaign case whose data cannot be read
DAMAGED = "damaged"


@dataclass(frozen=True)
class CaseData:
    case_id: str
    parameters: dict           # the four sweepable physics parameters
    status: str
    t: float                   # reached
    t_end: float
    message: str
    series: dict
    search: int = -1           # search files: the search the case belongs to
    mark: tuple = ()           # (status, t, samples, snapshots) when read: tells whether it changed since
    decided: str = ""          # the regime a run with run.until_decided stopped on ("": none)
    rtol: float = math.nan     # numerics.rtol of an adaptive run (nan: fixed step)
    N: float = math.nan        # numerics.N (a refinement may run a point again at a larger N); where N
                               # adapts (numerics.N_max > 0), the largest N the run took
    patterns: dict = field(default_factory=dict)   # t, psi, curvature of the last PATTERN_SNAPSHOTS snapshots
    resolution: dict = field(default_factory=dict)  # the numerics a refinement's run again may change (resolution)
    wall: float = math.nan     # the wall seconds its runs took (progress)


#: how many of a case's last snapshots its pattern's topology is read from (those after t_settle)
PATTERN_SNAPSHOTS = 16
#: the columns a row gets from them (nan without snapshots): soft domains, how many sit on the tips,
#: two-fold symmetry (1/0), and whether every snapshot read had the same topology (1/0)
TOPOLOGY_COLUMNS = ("soft_domains", "domains_on_tips", "two_fold", "topology_steady")
#: the rheology series (model/rheology.py) a row gives the settled mean of, and the columns of each: the
#: mean, its statistical, time-step and grid errors (as theta_mean's), and the amplitude (nan for a case
#: of a format before them, or not settled)
STRESS_SERIES = ("intrinsic_viscosity", "normal_stress_coefficient")
STRESS_COLUMNS = tuple(f"{name}{suffix}" for name in STRESS_SERIES
                       for suffix in ("", "_err", "_dt_err", "_N_err", "_amplitude"))


def case_data(store: CaseStore, case_id: str, search: int = -1) -> CaseData:
    attrs = store.attrs
    t, t_end, wall = (float(v) for v in store.progress[:3])
    series = store.timeseries()
    N = float(attrs.get("numerics.N", math.nan))
    if float(attrs.get("numerics.N_max", 0)) > 0 and len(series.get("N", ())):
        N = float(np.max(series["N"]))
    return CaseData(case_id, {k: float(parameter_of(attrs, k, "physics.")) for k in PARAMETERS},
                    STATUS_NAMES.get(store.status, str(store.status)), t, t_end, store.message, series,
                    search, mark(store), REGIMES_BY_CODE.get(store.decision[0], ""),
                    float(attrs.get("numerics.rtol", math.nan)), N,
                    store.last_snapshots(("t", "psi", "curvature"), PATTERN_SNAPSHOTS), resolution(attrs), wall)


def resolution(attrs) -> dict:
    """The numerics a refinement's run again may change (campaign.study.Study.retry_numerics: N, N_max,
    resize_tail, rtol), as a case's attributes hold them (rtol: an adaptive run's)."""
    kinds = {"N": int, "N_max": int, "resize_tail": float, "rtol": float}
    out = {k: kind(attrs[f"numerics.{k}"]) for k, kind in kinds.items() if f"numerics.{k}" in attrs}
    if not math.isfinite(out.get("rtol", 0.0)):          # a fixed-step run: none to change (NaN is no value)
        del out["rtol"]
    return out


def mark(store: CaseStore) -> tuple:
    """What changes while a case runs: (status, t reached, samples, snapshots)."""
    return store.status, float(store.progress[0]), store.n_samples, store.n_snapshots


#: how a failed case's reason begins in regimes.csv
FAILED_PREFIX = "case failed: "


@dataclass(frozen=True)
class Verdict:
    """What a staged campaign decides on for one ended case: its regime (regimes.csv's) and whether it
    failed as under-resolved, crept, or stayed unsettled (the three reasons a refinement runs a point
    again)."""

    regime: str
    under_resolved: bool = False
    crept: bool = False
    unsettled: bool = False

    @classmethod
    def of(cls, row: dict) -> "Verdict":
        return cls(row["regime"], under_resolved(row), crept(row), unsettled(row))

    @property
    def code(self) -> int:
        """8 x its regime's place in VERDICT_REGIMES + 4 unsettled + 2 under_resolved + crept; -1 for a
        regime not there (never stored)."""
        if self.regime not in VERDICT_REGIMES:
            return -1
        return 8 * VERDICT_REGIMES.index(self.regime) + 4 * self.unsettled + 2 * self.under_resolved + self.crept

    @classmethod
    def from_code(cls, code) -> "Verdict | None":
        """The verdict of a stored code; None for -1 (none stored) or a code that is none."""
        if not np.isfinite(code) or code != int(code) or not 0 <= code < 8 * len(VERDICT_REGIMES):
            return None
        regime, flags = divmod(int(code), 8)
        return cls(VERDICT_REGIMES[regime], bool(flags & 2), bool(flags & 1), bool(flags & 4))


#: the regimes a stored verdict may hold, in the order of their codes
VERDICT_REGIMES = ("TT", "PT", "TU", UNDECIDED, FAILED_OUTCOME, MODEL_LIMIT_OUTCOME)

#: the modules a case's verdict is computed by (its data read, classified, the reasons to run again)
_CLASSIFIER_MODULES = ("hpcves.analysis.regimes", "hpcves.analysis.periodicity", "hpcves.analysis.pattern",
                       "hpcves.analysis.accuracy", "hpcves.run.verdict", "hpcves.run.decision")


@functools.cache
def classifier() -> str:
    """What the stored verdicts of a file were computed by: SHA-256 (first 16 hex digits) of the source
    of every module that computes them. Verdicts stored by other code are not taken (its version
    number does not change with every change of the classification)."""
    import hashlib
    import importlib
    import inspect

    digest = hashlib.sha256()
    for name in _CLASSIFIER_MODULES:
        digest.update(inspect.getsource(importlib.import_module(name)).encode())
    return digest.hexdigest()[:16]


def verdict_of(data: CaseData, settings: AnalysisSettings) -> tuple[Verdict, float]:
    """(the verdict on an ended case, the wall seconds its file holds): what a staged campaign keeps of
    it in index/verdict. Classified on the rank that ran the case, right after it ended, or on rank 0
    between stages."""
    return Verdict.of(analyze_case(data, settings)), data.wall


def under_resolved(row: dict) -> bool:
    """Whether a regimes.csv row is a case that failed because its N did not resolve it."""
    return row["regime"] == FAILED_OUTCOME and row["reason"].startswith(f"{FAILED_PREFIX}{UNDER_RESOLVED}")


def unsettled(row: dict) -> bool:
    """Whether a regimes.csv row is an undecided case whose theta neither settled nor repeated, or kept
    drifting, to the end of its run (regimes.UNSETTLED): possibly a motion its step's tolerance misses."""
    return row["regime"] == UNDECIDED and UNSETTLED.search(row["reason"]) is not None


def crept(row: dict) -> bool:
    """Whether a regimes.csv row is an undecided case whose theta settled steady while its pattern kept
    moving (regimes.CREEPING): the creep of a tank-treading pattern where the grid is too coarse."""
    return row["regime"] == UNDECIDED and CREEPING.search(row["reason"]) is not None


def analyze_case(case: CaseData, settings: AnalysisSettings) -> dict:
    """One row of regimes.csv (COLUMNS) for one case."""
    base = {"case": case.case_id, **case.parameters, "status": case.status, "t": case.t, "t_end": case.t_end,
            "rtol": case.rtol, "N": case.N}
    n = len(case.series["t"])
    unclassified = {STATUS_NAMES[FAILED]: (FAILED_OUTCOME, FAILED_PREFIX),
                    STATUS_NAMES[MODEL_LIMIT]: (MODEL_LIMIT_OUTCOME, f"stopped at t = {case.t:.4g}: "),
                    DAMAGED: (UNDECIDED, "case damaged: ")}
    if case.status in unclassified or n == 0:
        first = case.message.splitlines()[0] if case.message else ""
        regime, prefix = unclassified.get(case.status, (UNDECIDED, "not run yet"))
        reason = prefix + first.removeprefix(MODEL_LIMIT_PREFIX) if case.status in unclassified else prefix
        empty = Classification(regime, reason, *([math.nan] * (len(fields(Classification)) - 2)))
        return {**base, **empty.row(), "period_dt_err": math.nan, "theta_mean_dt_err": math.nan,
                "period_N_err": math.nan, "theta_mean_N_err": math.nan,
                **dict.fromkeys(STRESS_COLUMNS, math.nan), **dict.fromkeys(TOPOLOGY_COLUMNS, math.nan)}
    found = classify(case.series, settings)
    if case.status != STATUS_NAMES[FINISHED]:
        found = replace(found, reason=f"{case.status} at t = {case.t:.4g} of {case.t_end:.4g}: {found.reason}")
    elif case.decided:                                    # stopped by run.until_decided (decision.py)
        regime = case.decided
        note = (f"stopped when decided at t = {case.t:.4g} (cap {case.t_end:.4g})" if regime == found.regime else
                f"the run decided {regime} at t = {case.t:.4g} and stopped, but these thresholds find "
                f"{found.regime}: rerun to the cap without run.until_decided")
        found = replace(found, reason=f"{note}; {found.reason}")
    rtol = case.rtol if math.isfinite(case.rtol) else None
    flips = bool(found.theta_min < 0)                     # tumbling: no rule (accuracy.py)
    series = case.series
    tail = accuracy.settled_tail(series["t"], series.get("tail_theta"), series.get("tail_psi"), found.t_settle)
    return {**base, **found.row(), "period_dt_err": accuracy.period_error(found.period, rtol, flips),
            "theta_mean_dt_err": accuracy.inclination_error(found.theta_mean, rtol, flips),
            "period_N_err": accuracy.spatial_period_error(found.period, tail, flips),
            "theta_mean_N_err": accuracy.spatial_inclination_error(found.theta_mean, tail, flips),
            **stress_columns(series, found, rtol, tail, flips), **pattern_columns(case.patterns, found.t_settle)}


def stress_columns(series: dict, found: Classification, rtol: float | None, tail: float, flips: bool) -> dict:
    """The rheology columns of a row: each series' settled mean over theta's settled part and whole periods
    (analysis/stress.py), with the error bars of accuracy.stress_step_error and stress_grid_error; nan where
    the case is not settled (undecided) or its file has no such series."""
    out = {}
    settled = found.regime != UNDECIDED and math.isfinite(found.t_settle)
    for name in STRESS_SERIES:
        values = series.get(name)
        mean = settled_mean(series["t"], values, found.t_settle, found.period, found.period_err) \
            if settled and values is not None and len(values) else SettledMean.none()
        out |= {name: mean.mean, f"{name}_err": mean.error,
                f"{name}_dt_err": accuracy.stress_step_error(name, rtol, flips) if math.isfinite(mean.mean)
                else math.nan,
                f"{name}_N_err": accuracy.stress_grid_error(name, tail, flips) if math.isfinite(mean.mean)
                else math.nan,
                f"{name}_amplitude": mean.amplitude}
    return out


def pattern_columns(patterns: dict, t_settle: float) -> dict:
    """The topology columns of a row from the last snapshots (those from t_settle on, where it is known)."""
    t = patterns.get("t", ())
    chosen = [i for i in range(len(t)) if not math.isfinite(t_settle) or t[i] >= t_settle]
    found, steady = common_topology([patterns["psi"][i] for i in chosen], [patterns["curvature"][i] for i in chosen])
    if found is None:
        return dict.fromkeys(TOPOLOGY_COLUMNS, math.nan)
    return {"soft_domains": float(found.domains), "domains_on_tips": float(found.on_tips),
            "two_fold": float(found.two_fold), "topology_steady": float(steady)}
