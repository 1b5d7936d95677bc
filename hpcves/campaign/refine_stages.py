"""The ``[refine]`` campaign mode: regime boundaries over two parameters, refined stage by stage.

A refine study holds one refinement per combination of its swept keys that
are not axes of the plane. As in ``[search]`` (search_stages.py), the
campaign runs in stages: every case the refinements asked for runs under the
same MPI scheduler; then rank 0 classifies the finished cases
(:func:`hpcves.analysis.regimes.classify`, the study's ``[analysis]`` thresholds), lets
every refinement take its next step (:func:`hpcves.analysis.refine.step`) and adds the
points they ask for as new cases. Nothing about a refinement is stored but its
cases: a resumed campaign replays their regimes and asks for the same points. A
point's cases after its first are its runs again: at a larger N after under-resolved
ones (``[refine] max_N``: N doubles with each), with a tighter resize_tail after
creeping ones (``[refine] min_resize_tail``); each takes the numerics its file holds.

This module reads the file; the logic is in analysis/refine.py, the tables of the
boundaries in reports/refinement.py.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from hpcves.analysis.refine import BUDGET, RUNNING, RefineSettings, RefineState, boundary, joint, step
from hpcves.campaign.search_stages import StageDriver
from hpcves.campaign.study import Study
from hpcves.model.params import LABELS
from hpcves.run.verdict import resolution


@dataclass(frozen=True)
class RefineOutcome:
    """Where one refinement stands: its fixed values, its state, the regimes found on its plane."""

    index: int
    point: dict                # the values of the swept keys that are not axes
    state: RefineState
    regimes: dict              # {(x, y): regime} of its classified cases (a point's last run)
    settings: RefineSettings
    retries: dict = field(default_factory=dict)   # {(x, y, start): (attempt, numerics)} of runs to run again
    spent: int = 0             # its cases (a point run again counts each time)
    runs: int = 0              # its distinct runs: points (and starts, in a refinement of attractors)
    starts: int = 1            # runs a point: the starts of a refinement of attractors

    def row(self) -> dict:
        """One row of refinement.csv."""
        crossings = boundary(self.settings, self.regimes, self.state.cells) if self.regimes else []
        reason = self.state.reason
        if self.starts > 1:            # refine.step counts points; each ran from every start
            reason = reason.replace(" cases)", f" points, {self.starts} starts each)")
        if self.state.status == RUNNING:
            reason = f"unfinished: {len(self.state.next_points)} points to run next ({reason})"
        return {**self.point, "status": self.state.status, "cases": self.spent,
                "run_again": self.spent - (self.runs or len(self.regimes)),
                "full_grid_cases": self.settings.full_grid_cases() * self.starts,
                "crossings": len(crossings), "blurry": sum(c.blurry for c in crossings), "reason": reason}

    def brief(self) -> str:
        """``Delta = 0.94: 41 cases, running``: one refinement in a few words."""
        where = ", ".join(f"{LABELS.get(k, k)} = {v:g}" for k, v in self.point.items())
        return f"{where + ': ' if where else ''}{self.spent} cases, {self.state.status}"


def outcomes(study: Study, found: list[tuple]) -> list[RefineOutcome]:
    """The state of every refinement from ``found`` = (refinement, x, y, regime, retry, start) of its
    ended cases, in case order (retry: what the point's next run changes, :meth:`Study.retry_numerics`,
    None when it runs no more; start: None, or which of [starts] in a refinement of attractors).

    A point's last run gives its regime. A point whose last run stopped as under-resolved, crept, or
    stayed unsettled, runs again while ``max_N``, ``min_resize_tail`` or ``min_rtol`` allow; until then the
    refinement takes it as not yet run (:func:`hpcves.analysis.refine.step`), and it runs again even
    where no cell needs it any more (:func:`again`). In a refinement of
    attractors each point runs from every start; its outcome is the set of regimes they reached
    (refine.joint), known once every start's last run is, and the budget is counted in points (each
    costs one case a start)."""
    settings = study.refine_settings
    starts = study.point_starts
    runs = [{} for _ in study.refinements]           # {(x, y, start): [retry of each run]}
    last = [{} for _ in study.refinements]           # {(x, y, start): regime of its last run}
    for refinement, x, y, regime, retry, start in found:
        runs[refinement].setdefault((x, y, start), []).append(retry)
        last[refinement][(x, y, start)] = regime
    states = []
    per_point = dataclasses.replace(settings, max_cases=settings.max_cases // len(starts))
    for i, (point, point_runs, regimes) in enumerate(zip(study.refinements, runs, last)):
        retries = {p: (len(r), r[-1]) for p, r in point_runs.items() if r[-1]}
        spent = sum(len(r) for r in point_runs.values())
        known = {}
        for x, y in {(x, y) for x, y, _ in regimes}:
            keys = [(x, y, s) for s in starts]
            if all(k in regimes and k not in retries for k in keys):
                known[(x, y)] = joint(regimes[k] for k in keys) if len(starts) > 1 else regimes[keys[0]]
        points_spent = -(-spent // len(starts))
        state = again(per_point, step(per_point, known, points_spent), retries, points_spent)
        shown = {(x, y): v for (x, y, _), v in regimes.items()} if len(starts) == 1 else known
        states.append(RefineOutcome(i, dict(point), state, shown, settings, retries, spent, len(point_runs),
                                    len(starts)))
    return states


def again(settings, state: RefineState, retries: dict, spent: int) -> RefineState:
    """``state`` with the points still to run again added to its next points, within the budget: once a
    cell's retried corners are decided it may need its finer points no more, but a point the map shows
    is not left at a run a retry can decide (a refinement continued with a lower min_resize_tail)."""
    extra = sorted({(x, y) for x, y, _ in retries} - set(state.next_points))
    left = settings.max_cases - spent - len(state.next_points)
    if not extra or state.status == BUDGET or left <= 0:
        return state
    extra = extra[:left]
    reason = state.reason if state.status == RUNNING else f"{len(extra)} points to run again ({state.reason})"
    return RefineState(RUNNING, tuple(sorted((*state.next_points, *extra))), state.cells, reason)


def attempts(points: list) -> list[int]:
    """How many times each point of ``points`` (in case order) came before: its run's attempt."""
    seen: dict = {}
    out = []
    for p in points:
        out.append(seen.get(p, 0))
        seen[p] = out[-1] + 1
    return out


def run_key(study: Study, c) -> tuple:
    """(refinement, x, y, start) of a refine study's case: what its runs again share (start: which of
    [starts] in a refinement of attractors, else None -- each start is a refinement of its own)."""
    x_key, y_key = study.refine.axes
    return c.search, c.swept[x_key], c.swept[y_key], c.swept.get("start") if study.refine.attractors else None


def run_again(study: Study) -> frozenset:
    """The ids of the cases whose point a later case runs again (at a larger N, a tighter resize_tail or rtol):
    their failures are taken care of (none outside a refine study)."""
    if not study.refine:
        return frozenset()
    last = {run_key(study, c): c.case_id for c in study.cases}
    return frozenset(c.case_id for c in study.cases if last[run_key(study, c)] != c.case_id)


class RefineDriver(StageDriver):
    """Rank 0's side of a refine campaign: classify what ended, ask for the next stage."""

    @staticmethod
    def cases_from_file(study: Study, campaign) -> Study:
        """``study`` with the cases its file holds already (the fingerprint guarantees they are this study's;
        a point's later cases are its runs again, with the resolution their file holds)."""
        x_key, y_key = study.refine.axes
        index = campaign.h5["index"]
        n = len(campaign.case_ids)
        starts = ([float(s) for s in index["start"][:n]] if study.refine.attractors else [None] * n)
        points = list(zip(campaign.searches_of_cases(), (float(x) for x in index[x_key][:n]),
                          (float(y) for y in index[y_key][:n]), starts))
        cases = [study.refine_case(r, x, y, case_id, resolution(campaign.store(case_id).attrs) if attempt
                                   else None, start)
                 for case_id, (r, x, y, start), attempt in zip(campaign.case_ids, points, attempts(points))]
        return study.with_cases(cases)

    def next_stage(self, study: Study, campaign) -> tuple[list[RefineOutcome], list]:
        """(outcome of every refinement, the new StudyCases to run: none once every one has ended)."""
        found = []
        for c in study.cases:
            verdict = self.verdict(campaign, c.case_id)
            if verdict is not None:
                r, x, y, start = run_key(study, c)
                found.append((r, x, y, verdict.regime, study.retry_numerics(c.case.numerics, verdict.under_resolved,
                                                                            verdict.crept, verdict.unsettled), start))
        states = outcomes(study, found)
        taken = {run_key(study, c) for c in study.cases}
        new = []
        for outcome in states:
            for x, y in outcome.state.next_points:
                for start in study.point_starts:
                    attempt, numerics = outcome.retries.get((x, y, start), (0, None))
                    if not attempt and (outcome.index, x, y, start) in taken:
                        if len(study.point_starts) > 1:       # this start's run is known: the point waits for others
                            continue
                        raise RuntimeError(f"refinement {outcome.index}: ({x:g}, {y:g}) was run but has not ended")
                    case_id = f"{len(study.cases) + len(new):0{study.id_width}d}"
                    new.append(study.refine_case(outcome.index, x, y, case_id, numerics, start))
        return states, new
