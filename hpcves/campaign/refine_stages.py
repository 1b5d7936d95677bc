"""The ``[refine]`` campaign mode: regime boundaries over two parameters, refined stage by stage.

A refine study holds one refinement per combination of its swept keys that
are not axes of the plane. As in ``[search]`` (search_campaign.py), the
campaign runs in stages: every case the refinements asked for runs under the
same MPI scheduler; then rank 0 classifies the finished cases
(:func:`hpcves.analysis.regimes.classify`, the study's ``[analysis]`` thresholds), lets
every refinement take its next step (:func:`hpcves.analysis.refine.step`) and adds the
points they ask for as new cases. Nothing about a refinement is stored but its
cases: a resumed campaign replays their regimes and asks for the same points.

This module reads the file and writes the boundaries; the logic is in refine.py.
"""
from __future__ import annotations

from dataclasses import dataclass
from hpcves.reports.analyze import LABELS, markdown_table
from hpcves.analysis.refine import RUNNING, RefineSettings, RefineState, boundary, polylines, step
from hpcves.campaign.search_stages import ENDED_NAMES, StageDriver, write_rows  # noqa: F401 (write_rows: for analysis, cli)
from hpcves.campaign.study import Study, study_from_toml


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


# ---------------------------------------------------------------------- tables of an analysis
def source_outcomes(source, rows: list[dict]) -> tuple[Study, list[RefineOutcome]]:
    """The refinements of a refine file (analysis.Source) replayed with its cases' regimes ``rows``
    (with thresholds other than the campaign's a refinement may want points the file lacks:
    its status is then "running")."""
    study = study_from_toml(source.toml, source=f"{source.path}: campaign_toml")
    x_key, y_key = study.refine.axes
    found = [(case.search, case.parameters[x_key], case.parameters[y_key], row["regime"])
             for case, row in zip(source.cases, rows) if row["status"] in ENDED_NAMES]
    return study, outcomes(study, found)


#: the columns of refinement.csv after the refinement's fixed values
REFINEMENT_FIELDS = ("status", "cases", "full_grid_cases", "crossings", "blurry", "reason")


def refinement_columns(study: Study) -> tuple:
    """The columns of refinement.csv: one row per refinement."""
    return tuple(study.refinements[0]) + REFINEMENT_FIELDS


def boundary_columns(study: Study) -> tuple:
    """The columns of boundaries.csv: the refinement's fixed values, the line, and each crossing
    with its bracket (the two cases of different outcomes it lies between)."""
    x_key, y_key = study.refine.axes
    return (tuple(study.refinements[0]) + ("line", "pair", "order", x_key, y_key, f"{x_key}_low", f"{x_key}_high",
                                           f"{y_key}_low", f"{y_key}_high", "blurry"))


def boundary_rows(study: Study, states: list[RefineOutcome]) -> list[dict]:
    """Every crossing of every refinement, chained into polylines (refine.polylines): one row each."""
    x_key, y_key = study.refine.axes
    out, line = [], 0
    for o in states:
        if not o.regimes:
            continue
        for pair, crossings in polylines(o.settings, o.regimes, o.state.cells):
            for k, c in enumerate(crossings):
                out.append({**o.point, "line": line, "pair": pair, "order": k, x_key: c.x, y_key: c.y,
                            f"{x_key}_low": c.x_low, f"{x_key}_high": c.x_high, f"{y_key}_low": c.y_low,
                            f"{y_key}_high": c.y_high, "blurry": int(c.blurry)})
            line += 1
    return out


def refinement_markdown(name: str, study: Study, states: list[RefineOutcome], rows: list[dict],
                        cases) -> str:
    """refinement.md: every refinement's verdict, then its blurry stretches with the reasons of the
    cases that blur them (``rows``: regimes.csv rows of ``cases``)."""
    settings = study.refine_settings
    x, y = settings.x, settings.y
    tolerance = dict(study.refine.tolerance)

    def tol(axis):
        return f"{tolerance[axis.key]:g}" + (" (relative)" if axis.log else "")

    keys = list(study.refinements[0])
    text = [f"# Regime boundaries of {name!r}\n",
            f"Refined over {LABELS.get(x.key, x.key)} x {LABELS.get(y.key, y.key)} from a coarse grid of "
            f"{len(x.values)} x {len(y.values)} points, splitting every mixed cell until it is within "
            f"{tol(x)} in {LABELS.get(x.key, x.key)} and {tol(y)} in {LABELS.get(y.key, y.key)} "
            f"(at most {settings.max_cases} cases per refinement). A crossing lies between two cases of "
            "different outcomes, on the edge of a finest cell; it is blurry when one of them is undecided, "
            "failed or at the model's limit. The full grid is the regular grid that brackets every boundary "
            "to the same tolerances everywhere. boundaries.csv holds the polylines.\n"]
    body = []
    for o in states:
        r = o.row()
        body.append([f"{r[k]:g}" for k in keys] + [r["status"], str(r["cases"]), str(r["full_grid_cases"]),
                                                   f"{100 * r['cases'] / r['full_grid_cases']:.0f} %",
                                                   str(r["crossings"]), str(r["blurry"]), r["reason"]])
    text.append(markdown_table([LABELS.get(k, k) for k in keys]
                               + ["status", "cases", "full grid", "share", "crossings", "blurry", "reason"],
                               body, left=(len(keys), len(keys) + 6)) + "\n")
    by_point = {}
    for case, row in zip(cases, rows):
        by_point[(case.search, case.parameters[x.key], case.parameters[y.key])] = row
    for o in states:
        blurry = [c for c in boundary(o.settings, o.regimes, o.state.cells) if c.blurry] if o.regimes else []
        if not blurry:
            continue
        where = ", ".join(f"{LABELS.get(k, k)} = {v:g}" for k, v in o.point.items())
        text.append(f"## Blurry stretches{' at ' + where if where else ''}\n")
        text.append("The cases that are not TT, PT or TU at the ends of blurry crossings, and why:\n")
        seen = set()
        for c in blurry:
            for point in ((c.x_low, c.y_low), (c.x_high, c.y_high)):          # the edge's two ends
                row = by_point.get((o.index, *point))
                if row is None or row["regime"] in ("TT", "PT", "TU") or row["case"] in seen:
                    continue
                seen.add(row["case"])
                text.append(f"* case {row['case']} ({LABELS.get(x.key, x.key)} = {point[0]:g}, "
                            f"{LABELS.get(y.key, y.key)} = {point[1]:g}): {row['regime']} -- "
                            f"{row['reason'].split('; ')[0]}")
        text.append("")
    return "\n".join(text) + "\n"
