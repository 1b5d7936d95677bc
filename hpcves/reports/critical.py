"""critical_shear.csv and critical_shear.md: the verdict of every critical-shear search (critical_lambda.csv
and .md for searches along lambda, with lambda_C)."""
from __future__ import annotations

import math
from pathlib import Path

from hpcves.analysis.search import AXES, CENTRE, CONVERGED, estimate_critical
from hpcves.campaign.search_stages import outcomes, search_points
from hpcves.campaign.study import search_keys
from hpcves.model.params import LABELS
from hpcves.reports.tables import fmt, markdown_table, write_rows
from hpcves.run.store import ENDED_NAMES


def critical_columns(along: str = "shear_rate") -> tuple:
    """The columns of critical_shear.csv (critical_lambda.csv for ``along`` = "viscosity_ratio"): the search's
    point, S_C (lambda_C: a best estimate inside the bracket), S_C_from (how it was found), its bracket,
    bending_gap (Delta E_b of the case at bracket_high, the smallest phase-treading value; nan if none),
    status, cases, reason."""
    return search_keys(along) + (AXES[along][1], f"{AXES[along][1]}_from", "bracket_low", "bracket_high",
                                 "bending_gap", "bending_gap_err", "status", "cases", "reason")


#: the columns of critical_shear.csv
CRITICAL_COLUMNS = critical_columns()


def write_critical_csv(rows: list[dict], path: Path, along: str = "shear_rate") -> None:
    """critical_shear.csv: one row per search (:func:`critical_columns`)."""
    write_rows(rows, critical_columns(along), path)


def critical_rows(source, rows: list[dict], study) -> list[dict]:
    """critical_shear.csv rows of a search file (analysis.Source, made from ``study``) from its cases'
    classification ``rows``.

    The searches are replayed with these regimes: with the campaign's own
    ``[analysis]`` thresholds they reproduce the campaign's verdicts; with
    others (``--set``) a search may want cases the file does not hold (its
    status is then "running", its reason names them).
    """
    along = study.search.along
    found = [(case.search, case.parameters[along], row["regime"]) for case, row in zip(source.cases, rows)
             if row["status"] in ENDED_NAMES]
    searched = outcomes(study.search, search_points(study), found, tuple(study.sweep))
    gaps, motions = {}, [{} for _ in searched]
    for case, row in zip(source.cases, rows):
        gaps[(case.search, case.parameters[along])] = (row["bending_gap"], row["bending_gap_err"])
        if row["status"] in ENDED_NAMES:
            motions[case.search][case.parameters[along]] = (row["regime"], row["theta_mean"], row["period"])
    out = []
    for o in searched:
        row = o.row()
        if o.state.status == CONVERGED:
            estimate = estimate_critical(o.state.low, o.state.high, motions[o.index])
            if math.isfinite(estimate.value):
                row[o.column], row[f"{o.column}_from"] = estimate.value, estimate.method
            else:
                row[o.column], row[f"{o.column}_from"] = o.state.centre, f"{CENTRE}: {estimate.method}"
        row["bending_gap"], row["bending_gap_err"] = gaps.get((o.index, o.state.high), (math.nan, math.nan))
        out.append(row)
    return out


def critical_table(rows: list[dict], keys, column: str = "S_C") -> str:
    """Markdown table of critical_shear.csv rows: the ``keys`` of each search, then the bracket of its
    critical value (``column``: S_C or lambda_C) and, where the rows have them (hpcves analyze's), the best
    estimate inside it and how it was found."""
    estimates = any(r.get(f"{column}_from") for r in rows)
    body = [[f"{r[k]:g}" for k in keys] + [f"[{fmt(r['bracket_low'], '.4g')}, {fmt(r['bracket_high'], '.4g')}]"]
            + ([fmt(r[column], ".4g"), r[f"{column}_from"]] if estimates else [])
            + [_gap(r["bending_gap"], r["bending_gap_err"]), str(r["cases"]), r["status"], r["reason"]]
            for r in rows]
    shift = 2 if estimates else 0
    return markdown_table([LABELS.get(k, k) for k in keys] + [f"{column} lies in"]
                          + (["best estimate", "found from"] if estimates else [])
                          + ["Delta E_b at the bracket's top", "cases", "status", "reason"],
                          body, left=((len(keys) + 2,) if estimates else ()) + (len(keys) + 3 + shift,
                                                                                 len(keys) + 4 + shift))


def _gap(gap: float, error: float) -> str:
    return f"{gap:.4g} +- {error:.1g}" if math.isfinite(gap) else ""


_ESTIMATE = ("The best estimate inside it: past the transition the period diverges as T ~ (x - x_C)^(-1/2), so "
             "1/T^2 of the two PT/TU cases nearest above the bracket (within 5 bracket widths), extrapolated linearly "
             "to zero, gives x_C; below a TT -> TU transition theta^2 of the two nearest TT cases gives another; those "
             "inside the bracket are averaged, the pair nearer the transition weighted more. Where none lands "
             "inside, the bracket's geometric centre stands in, and says so.")


def critical_markdown(name: str, searches: list[dict], along: str = "shear_rate") -> str:
    if along == "shear_rate":
        return (f"# Critical shear rates of {name!r}\n\nS_C lies in the bracket between the largest TT and the "
                f"smallest PT/TU shear rate: that is the result and its error bar. {_ESTIMATE} Delta E_b: the "
                "bending-energy gap (max - min of E_b over a period) of the phase-treading case at the bracket's "
                "top.\n\n"
                + critical_table(searches, search_keys(along)) + "\n")
    return (f"# Critical viscosity ratios of {name!r}\n\nlambda_C lies in the bracket between the largest "
            "tank-treading (TT) and the smallest phase-treading or tumbling (PT/TU) viscosity ratio lambda = eta_in "
            f"/ eta_out: that is the result and its error bar. {_ESTIMATE} Delta E_b: the bending-energy gap "
            "(max - min of E_b over a period) of the case at the bracket's top where it phase-treads.\n\n"
            + critical_table(searches, search_keys(along), AXES[along][1]) + "\n")
