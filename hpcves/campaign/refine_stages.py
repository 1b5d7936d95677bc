"""The ``[refine]`` campaign mode: regime boundaries over two parameters, refined stage by stage.

A refine study holds one refinement per combination of its swept keys that
are not axes of the plane. As in ``[search]`` (search_stages.py), the
campaign runs in stages: every case the refinements asked for runs under the
same MPI scheduler; then rank 0 classifies the finished cases
(:func:`hpcves.analysis.regimes.classify`, the study's ``[analysis]`` thresholds), lets
every refinement take its next step (:func:`hpcves.analysis.refine.step`) and adds the
points they ask for as new cases. Nothing about a refinement is stored but its
cases: a resumed campaign replays their regimes and asks for the same points.

This module reads the file; the logic is in analysis/refine.py, the tables of the
boundaries in reports/refinement.py.
"""
from __future__ import annotations

from dataclasses import dataclass

from hpcves.model.params import LABELS
from hpcves.analysis.refine import RUNNING, RefineSettings, RefineState, boundary, step
from hpcves.campaign.search_stages import StageDriver
from hpcves.campaign.study import Study


@dataclass(frozen=True)
class RefineOutcome:
    """Where one refinement stands: its fixed values, its state, the regimes found on its plane."""

    index: int
    point: dict                # the values of the swept keys that are not axes
    state: RefineState
    regimes: dict              # {(x, y): regime} of its classified cases
    settings: RefineSettings

    def row(self) -> dict:
        """One row of refinement.csv."""
        crossings = boundary(self.settings, self.regimes, self.state.cells) if self.regimes else []
        reason = self.state.reason
        if self.state.status == RUNNING:
            reason = f"unfinished: {len(self.state.next_points)} points to run next ({reason})"
        return {**self.point, "status": self.state.status, "cases": len(self.regimes),
                "full_grid_cases": self.settings.full_grid_cases(),
                "crossings": len(crossings), "blurry": sum(c.blurry for c in crossings), "reason": reason}

    def brief(self) -> str:
        """``Delta = 0.94: 41 cases, running``: one refinement in a few words."""
        where = ", ".join(f"{LABELS.get(k, k)} = {v:g}" for k, v in self.point.items())
        return f"{where + ': ' if where else ''}{len(self.regimes)} cases, {self.state.status}"


def outcomes(study: Study, found: list[tuple[int, float, float, str]]) -> list[RefineOutcome]:
    """The state of every refinement from ``found`` = (refinement, x, y, regime) of its ended cases."""
    settings = study.refine_settings
    by_refinement = [{} for _ in study.refinements]
    for refinement, x, y, regime in found:
        by_refinement[refinement][(x, y)] = regime
    return [RefineOutcome(i, dict(point), step(settings, regimes), regimes, settings)
            for i, (point, regimes) in enumerate(zip(study.refinements, by_refinement))]


class RefineDriver(StageDriver):
    """Rank 0's side of a refine campaign: classify what ended, ask for the next stage."""

    @staticmethod
    def cases_from_file(study: Study, campaign) -> Study:
        """``study`` with the cases its file holds already (the fingerprint guarantees they are this study's)."""
        x_key, y_key = study.refine.axes
        index = campaign.h5["index"]
        xs, ys = index[x_key][:], index[y_key][:]
        cases = [study.refine_case(r, float(x), float(y), case_id)
                 for case_id, r, x, y in zip(campaign.case_ids, campaign.searches_of_cases(), xs, ys)]
        return study.with_cases(cases)

    def next_stage(self, study: Study, campaign) -> tuple[list[RefineOutcome], list]:
        """(outcome of every refinement, the new StudyCases to run: none once every one has ended)."""
        x_key, y_key = study.refine.axes
        found = []
        for c in study.cases:
            regime = self.regime(campaign, c.case_id)
            if regime is not None:
                found.append((c.search, c.swept[x_key], c.swept[y_key], regime))
        states = outcomes(study, found)
        taken = {(c.search, c.swept[x_key], c.swept[y_key]) for c in study.cases}
        new = []
        for outcome in states:
            for x, y in outcome.state.next_points:
                if (outcome.index, x, y) in taken:          # asked for, not ended: cannot happen after a stage
                    raise RuntimeError(f"refinement {outcome.index}: ({x:g}, {y:g}) was run but has not ended")
                case_id = f"{len(study.cases) + len(new):0{study.id_width}d}"
                new.append(study.refine_case(outcome.index, x, y, case_id))
        return states, new
