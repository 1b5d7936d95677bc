"""refinement.csv, boundaries.csv and refinement.md: the verdict of every refinement and its
boundaries as polylines, from a refine file's cases."""
from __future__ import annotations

import dataclasses
import re
from collections import Counter

from hpcves.analysis.refine import CREEP_TIGHTENING, boundary, polylines
from hpcves.campaign.refine_stages import RefineOutcome, outcomes
from hpcves.campaign.study import Study, study_from_toml
from hpcves.model.params import LABELS
from hpcves.reports.tables import markdown_table
from hpcves.run.store import ENDED_NAMES
from hpcves.run.verdict import DAMAGED, crept, under_resolved, unsettled


def _run_keys(source, study: Study) -> list[tuple]:
    """(refinement, x, y, start) of every case of a refine file, in case order (refine_stages.run_key)."""
    x_key, y_key = study.refine.axes
    names = [name for name, _ in study.starts]
    starts = [float(names.index(s)) if study.refine.attractors else None
              for s in (source.starts or [None] * len(source.cases))]
    return [(case.search, case.parameters[x_key], case.parameters[y_key], start)
            for case, start in zip(source.cases, starts)]


def superseded(source) -> frozenset:
    """The ids of a refine file's cases whose point a later case runs again (a larger N, a tighter
    resize_tail): the later run is the point's (none outside a refine file)."""
    if source.mode != "refine":
        return frozenset()
    keys = _run_keys(source, study_from_toml(source.toml, source=f"{source.path}: campaign_toml"))
    last = {key: case.case_id for key, case in zip(keys, source.cases)}
    return frozenset(case.case_id for key, case in zip(keys, source.cases) if last[key] != case.case_id)


def source_outcomes(source, rows: list[dict]) -> tuple[Study, list[RefineOutcome]]:
    """The refinements of a refine file (analysis.Source) replayed with its cases' regimes ``rows``
    (with thresholds other than the campaign's a refinement may want points the file lacks:
    its status is then "running")."""
    study = study_from_toml(source.toml, source=f"{source.path}: campaign_toml")
    found = [(r, x, y, row["regime"],
              study.retry_numerics(dataclasses.replace(study.base.numerics, **case.resolution), under_resolved(row),
                                   crept(row), unsettled(row)), start)
             for (r, x, y, start), case, row in zip(_run_keys(source, study), source.cases, rows)
             if row["status"] in ENDED_NAMES or row["status"] == DAMAGED]   # damaged: ended for the campaign
    return study, outcomes(study, found)


#: the columns of refinement.csv after the refinement's fixed values
REFINEMENT_FIELDS = ("status", "cases", "run_again", "full_grid_cases", "crossings", "blurry", "reason")


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


def _cause(reason: str) -> str:
    """The kind of a reason, without its numbers: "case failed: under-resolved: the top third ..."
    -> "under-resolved", "only 2.2 settled periods of 15.35 (at least 3)" -> "only n settled periods of n"."""
    text = reason.split("; ")[0].removeprefix("case failed: ")
    while re.search(r"\([^()]*\)", text):
        text = re.sub(r"\s*\([^()]*\)", "", text)             # parentheses, innermost first
    text = re.split(r":| --", text, maxsplit=1)[0]
    return re.sub(r"[-+]?\d+(\.\d+)?(e[-+]?\d+)?", "n", text).strip()


def blurring_summary(ends: list[tuple[str, str, float, float]], x_label: str, y_label: str) -> str:
    """What blurs the boundaries, one clause per outcome: its cases counted by cause and the span of
    the axes they lie in. ``ends``: (regime, reason, x, y) of each case that blurs a crossing."""
    if not ends:
        return "every case at their ends was decided"
    clauses = []
    for regime in sorted({e[0] for e in ends}, key=lambda r: -sum(e[0] == r for e in ends)):
        mine = [e for e in ends if e[0] == regime]
        causes = Counter(_cause(e[1]) for e in mine).most_common()
        spans = [f"{label} = " + (f"{min(v):.3g}" if f"{min(v):.3g}" == f"{max(v):.3g}" else
                                  f"{min(v):.3g} to {max(v):.3g}")
                 for label, v in ((x_label, [e[2] for e in mine]), (y_label, [e[3] for e in mine]))]
        clauses.append(f"{len(mine)} {regime} ({', '.join(f'{c}: {n}' for c, n in causes)}) at {', '.join(spans)}")
    return "blurred by " + "; ".join(clauses)


def refinement_markdown(name: str, study: Study, states: list[RefineOutcome], rows: list[dict],
                        cases) -> str:
    """refinement.md: every refinement's verdict, then its blurry stretches with the reasons of the
    cases that blur them (``rows``: regimes.csv rows of ``cases``)."""
    settings = study.refine_settings
    retrying = bool(settings.max_N or settings.min_resize_tail)
    x, y = settings.x, settings.y
    tolerance = dict(study.refine.tolerance)

    def tol(axis):
        return f"{tolerance[axis.key]:g}" + (" (relative)" if axis.log else "")

    keys = list(study.refinements[0])
    text = [f"# Regime boundaries of {name!r}\n",
            f"Refined over {LABELS.get(x.key, x.key)} x {LABELS.get(y.key, y.key)} from a coarse grid of "
            f"{len(x.values)} x {len(y.values)} points, splitting every mixed cell until every crossing is "
            f"bracketed to {tol(x)} in {LABELS.get(x.key, x.key)} and {tol(y)} in {LABELS.get(y.key, y.key)} "
            f"(at most {settings.max_cases} cases per refinement)"
            + (". " if settings.straight_span == 1 else
               f"; a boundary that crosses a cell from side to side is taken as straight over at most "
               f"{settings.straight_span:g} tolerances along it (refine.straight_span). ")
            + (f"An under-resolved case runs again at 2 N (where N adapts: N_max doubled) while that is at most "
               f"N = {settings.max_N} (refine.max_N). " if settings.max_N else "")
            + (f"A creeping case (theta steady, the pattern moving: regimes.CREEPING) runs again with "
               f"numerics.resize_tail / {CREEP_TIGHTENING:g} while that is at least {settings.min_resize_tail:g} "
               "(refine.min_resize_tail). " if settings.min_resize_tail else "")
            + ("'cases' counts every run, 'run again' the runs after a point's first. " if retrying else "")
            + "A crossing lies between two cases of "
            "different outcomes, on the edge of a finest cell; it is blurry when one of them is undecided, "
            "failed or at the model's limit. The full grid is the regular grid that brackets every boundary "
            "to the same tolerances everywhere. boundaries.csv holds the polylines.\n"]
    body = []
    for o in states:
        r = o.row()
        again = [str(r["run_again"])] if retrying else []
        body.append([f"{r[k]:g}" for k in keys] + [r["status"], str(r["cases"])] + again
                    + [str(r["full_grid_cases"]), f"{100 * r['cases'] / r['full_grid_cases']:.0f} %",
                       str(r["crossings"]), str(r["blurry"]), r["reason"]])
    header = (["status", "cases"] + (["run again"] if retrying else [])
              + ["full grid", "share", "crossings", "blurry", "reason"])
    text.append(markdown_table([LABELS.get(k, k) for k in keys] + header,
                               body, left=(len(keys), len(keys) + len(header) - 1)) + "\n")
    by_point = {}
    for case, row in zip(cases, rows):
        by_point[(case.search, case.parameters[x.key], case.parameters[y.key])] = row
    for o in states:
        blurry = [c for c in boundary(o.settings, o.regimes, o.state.cells) if c.blurry] if o.regimes else []
        if not blurry:
            continue
        where = ", ".join(f"{LABELS.get(k, k)} = {v:g}" for k, v in o.point.items())
        text.append(f"## Blurry stretches{' at ' + where if where else ''}\n")
        ends, seen = [], set()
        for c in blurry:
            for point in ((c.x_low, c.y_low), (c.x_high, c.y_high)):          # the edge's two ends
                row = by_point.get((o.index, *point))
                if row is None or row["regime"] in ("TT", "PT", "TU") or row["case"] in seen:
                    continue
                seen.add(row["case"])
                ends.append((row, point))
        summary = blurring_summary([(row["regime"], row["reason"], *point) for row, point in ends],
                                   LABELS.get(x.key, x.key), LABELS.get(y.key, y.key))
        text.append(f"{len(blurry)} of the crossings are blurry; {summary}.\n")
        text.append("The cases that are not TT, PT or TU at the ends of blurry crossings, and why:\n")
        for row, point in ends:
            text.append(f"* case {row['case']} ({LABELS.get(x.key, x.key)} = {point[0]:g}, "
                        f"{LABELS.get(y.key, y.key)} = {point[1]:g}): {row['regime']} -- "
                        f"{row['reason'].split('; ')[0]}")
        text.append("")
    return "\n".join(text) + "\n"
