"""The ``[search]`` campaign mode: critical-shear searches run stage by stage.

A search study holds one search per point of its sweep (psi_bar, Delta, B2; and S in a search along
lambda).
The campaign runs in stages: every case the searches asked for runs under the
same MPI scheduler; then rank 0 classifies the finished cases
(:func:`hpcves.analysis.regimes.classify`, with the study's ``[analysis]`` thresholds),
lets every search take its next step (:func:`hpcves.analysis.search.step`) and adds the
cases they ask for to the file. The searches advance together, so the cases of
all of them share the ranks.

Nothing about a search is stored but its cases: the state of every search is
recomputed from the regimes of the cases in the file, so a resumed campaign
takes the same steps and asks for the same cases as an uninterrupted one.

This module is the part that reads the file; the logic is in analysis/search.py, the
tables in reports/critical.py.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from hpcves.analysis.search import RUNNING, SearchSettings, SearchState, step
from hpcves.campaign.study import Study, search_keys
from hpcves.run.store import ENDED
from hpcves.run.verdict import Verdict, case_data, verdict_of


@dataclass(frozen=True)
class SearchOutcome:
    """Where one search stands: its parameters, its state, the regimes it found."""

    index: int
    point: dict                # psi_bar, excess_length, B2 (and S) of the search (swept or from the base case)
    state: SearchState
    regimes: dict              # {value searched along: regime} of its finished cases
    settings: SearchSettings   # the [search] table: what it runs along
    swept_keys: tuple = ()     # the keys of ``point`` that the study sweeps

    @property
    def symbol(self) -> str:
        return self.settings.symbol

    @property
    def column(self) -> str:
        """The critical value's column: S_C, or lambda_C in a search along lambda."""
        return self.settings.column

    def row(self) -> dict:
        """One row of critical_shear.csv (critical_lambda.csv): the bracket, and no estimate inside it (the
        campaign knows the cases' regimes, not their periods: reports/critical.py estimates)."""
        reason = self.state.reason
        if self.state.status == RUNNING:
            reason = (f"unfinished: next {self.symbol} = {', '.join(f'{s:g}' for s in self.state.next_values)} "
                      f"({reason})")
        return {**self.point, self.column: math.nan, f"{self.column}_from": "", "bracket_low": self.state.low,
                "bracket_high": self.state.high, "bending_gap": math.nan, "bending_gap_err": math.nan,
                "status": self.state.status, "cases": len(self.regimes), "reason": reason}


def outcomes(settings: SearchSettings, points: list[dict], found: list[tuple[int, float, str]],
             swept_keys: tuple = ()) -> list[SearchOutcome]:
    """The state of every search from ``found`` = (search, value searched along, regime) of its finished
    cases."""
    by_search = [{} for _ in points]
    for search, value, regime in found:
        by_search[search][value] = regime
    return [SearchOutcome(i, point, step(settings, regimes), regimes, settings, tuple(swept_keys))
            for i, (point, regimes) in enumerate(zip(points, by_search))]


def search_points(study: Study) -> list[dict]:
    """psi_bar, excess_length and B2 (and S in a search along lambda) of every search of ``study``."""
    physics = study.base.physics
    return [{k: float(point.get(k, getattr(physics, k))) for k in search_keys(study.search.along)}
            for point in study.searches]


def cases_from_file(study: Study, campaign) -> Study:
    """``study`` with the cases its file holds already (a resumed search; the file's fingerprint
    guarantees they are the cases this study makes)."""
    searches = campaign.searches_of_cases()
    values = campaign.h5[f"index/{study.search.along}"][:]
    cases = [study.search_case(search, float(v), case_id)
             for case_id, search, v in zip(campaign.case_ids, searches, values)]
    return study.with_cases(cases)


class StageDriver:
    """Rank 0's side of a staged campaign (search or refine): the verdicts of the cases that ended.

    A case is classified once: its verdict is kept in the file (index/verdict, with the case's wall
    seconds then), and taken from there while the case's wall seconds are the same -- a case run
    again (--retry-failed) has more -- and the file's verdicts come from this classifier.
    """

    def __init__(self, study: Study, states: dict | None = None):
        self.settings = study.analysis
        #: {case id: (status, wall seconds)} known already (``hpcves status`` read them); else read here
        self.states = states or {}
        self._verdicts: dict[str, Verdict] = {}      # ended cases only
        self._stored: dict | None = None
        #: {case id: (code, wall)} classified here and not yet stored (stages.py stores them)
        self.fresh: dict[str, tuple[int, float]] = {}

    def verdict(self, campaign, case_id: str) -> Verdict | None:
        """The verdict on one case, or None while it has not ended."""
        if case_id in self._verdicts:
            return self._verdicts[case_id]
        if self._stored is None:
            self._stored = campaign.stored_verdicts()
        state = self.states.get(case_id) or campaign.state(case_id)
        if state[0] not in ENDED:
            return None
        stored = self._stored.get(case_id)
        verdict = Verdict.from_code(stored[0]) if stored is not None and stored[1] == state[1] else None
        if verdict is None:
            verdict = verdict_of(case_data(campaign.store(case_id), case_id), self.settings)[0]
            if verdict.code >= 0:
                self.fresh[case_id] = (verdict.code, state[1])
        self._verdicts[case_id] = verdict
        return verdict

    def ran(self, results) -> None:
        """Take the verdicts the ranks that ran the cases sent with them (CaseResult.verdict: (code, wall
        seconds)), so that none of those cases is read and classified here between stages."""
        for result in results:
            if result.verdict is not None and result.status in ENDED:
                code, wall = result.verdict
                verdict = Verdict.from_code(code)
                if verdict is not None:
                    self._verdicts[result.case_id] = verdict
                    self.fresh[result.case_id] = (code, wall)

    def regime(self, campaign, case_id: str) -> str | None:
        """The regime of one case, or None while it has not ended."""
        verdict = self.verdict(campaign, case_id)
        return None if verdict is None else verdict.regime


class SearchDriver(StageDriver):
    """Rank 0's side of a search campaign: classify what finished, ask for the next stage."""

    def __init__(self, study: Study, states: dict | None = None):
        super().__init__(study, states)
        self.points = search_points(study)

    cases_from_file = staticmethod(cases_from_file)

    def next_stage(self, study: Study, campaign) -> tuple[list[SearchOutcome], list]:
        """(outcome of every search, the new StudyCases to run: none once every search has ended)."""
        along = study.search.along
        found = []
        for c in study.cases:
            regime = self.regime(campaign, c.case_id)
            if regime is not None:
                found.append((c.search, c.swept[along], regime))
        states = outcomes(study.search, self.points, found, tuple(study.sweep))
        new = []
        taken = {(c.search, c.swept[along]) for c in study.cases}
        for outcome in states:
            for value in outcome.state.next_values:
                if (outcome.index, value) in taken:       # asked for, not finished: cannot happen after a stage
                    raise RuntimeError(f"search {outcome.index}: {outcome.symbol} = {value:g} was run but is "
                                       "not finished")
                case_id = f"{len(study.cases) + len(new):0{study.id_width}d}"
                new.append(study.search_case(outcome.index, value, case_id))
        return states, new
