"""``hpcves analyze``: regimes, periods, tables and figures of a campaign or run file."""
from __future__ import annotations

import click

from hpcves.analysis import accuracy
from hpcves.cli.terminal import OneLinePath, StatusLine, clean_errors, fail
from hpcves.model.params import ConfigError
from hpcves.reports.analyze import analyze, parse_overrides
from hpcves.reports.case_pages import SELECTIONS
from hpcves.reports.refinement import REFINEMENT_FIELDS


def _case_selection(which: str):
    """--case-figures: a named selection, or the case ids of a comma-separated list."""
    return which if which in SELECTIONS else [c.strip() for c in which.split(",") if c.strip()]


@click.command("analyze")
@click.argument("file", type=OneLinePath())
@click.option("--out", "out", type=OneLinePath(),
              help="Directory for the tables and figures (default: <file>_analysis next to the file).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a threshold of the classification, e.g. --set min_cycles=5 (see [analysis]).")
@click.option("--axes", help="The two parameters of the phase diagrams, e.g. shear_rate,psi_bar.")
@click.option("--no-write-back", is_flag=True, help="Do not store the results in the file's analysis/ group.")
@click.option("--case-figures", "which", default="auto", show_default=True,
              metavar="auto|all|flagged|none|ID,...",
              help="Whose one-page figures to draw: auto (every case's up to 100 cases, else the first 100 "
                   "flagged ones'), every case's, the flagged ones' (undecided, failed, unfinished), none, or "
                   "these case ids' (about 3 s a page, 1 s without streamlines).")
@click.option("--no-case-figures", is_flag=True, help="Same as --case-figures none.")
@click.option("--no-streamlines", is_flag=True,
              help="Case figures without the streamlines around the shapes (about 2 s a case less).")
@click.option("--jobs", "-j", type=click.IntRange(min=1), default=1, show_default=True,
              help="Processes that draw the case figures.")
@click.option("--markers", is_flag=True,
              help="Draw the cases as markers on the figures for a paper too (a search's or refinement's "
                   "phase diagrams; phase_diagram*_cases always shows every case).")
@clean_errors
def analyze_command(file, out, overrides, axes, no_write_back, which, no_case_figures, no_streamlines, jobs,
                    markers):
    """Regimes (TT / PT / TU / undecided), periods, tables and figures of a campaign or run file.

    Writes regimes.csv, regimes.md, periods.md, phase diagrams and period
    tables (PNG and PDF) and cases/<id>.png -- for a [search] campaign,
    critical_shear.csv/.md and S_C figures instead of the period tables (critical_lambda.csv/.md
    and lambda_C for a search along the viscosity ratio), for a
    [refine] campaign boundaries.csv (the polylines) and refinement.md; the
    results also go into the file's analysis/ group. The file may belong to a running campaign (then
    nothing is written into it).
    """
    axes_pair = None
    if axes:
        axes_pair = tuple(k.strip() for k in axes.split(","))
        if len(axes_pair) != 2:
            raise ConfigError(f"--axes {axes!r}: give two parameters, e.g. shear_rate,psi_bar")
    line = StatusLine()
    try:
        report = analyze(file, out, overrides=parse_overrides(overrides), write_to_file=not no_write_back,
                         case_figures="none" if no_case_figures else _case_selection(which), axes=axes_pair,
                         streamlines=not no_streamlines, jobs=jobs, markers=markers,
                         progress=lambda text: line.due(0.2) and line.show(text))
    finally:
        line.close()
    rows = report.rows
    for row in rows:
        period = ""
        if row["regime"] in ("PT", "TU") and row["period"] == row["period"]:
            error, dominant = accuracy.error_bar(row, "period")
            period = f"  T = {row['period']:.5g} +- {error:.1g} [{dominant}]"
        click.echo(f"{row['case']}  {row['regime']:<9}{period}  {row['reason']}")
    counts = ", ".join(f"{n} {r}" for r, n in report.counts().items())
    click.echo(f"{report.source.path}: {len(rows)} case{'s' * (len(rows) != 1)}: {counts}")
    for s in report.searches:
        where = f"psi_bar = {s['psi_bar']:g}, Delta = {s['excess_length']:g}, B2 = {s['B2']:g}"
        column = "S_C" if "S_C" in s else "lambda_C"
        if column == "lambda_C":
            where += f", S = {s['shear_rate']:g}"
        if s[column] == s[column]:
            click.echo(f"search {where}: {column} in [{s['bracket_low']:.4g}, {s['bracket_high']:.4g}], best "
                       f"estimate {s[column]:.4g} ({s[column + '_from']}; {s['cases']} cases)")
        else:
            click.echo(f"search {where}: {s['status']}  ({s['reason']})")

    for r in report.refinements:
        where = ", ".join(f"{k} = {r[k]:g}" for k in r if k not in REFINEMENT_FIELDS)
        click.echo(f"refinement{' ' + where if where else ''}: {r['status']}, {r['cases']} cases "
                   + (f"({r['run_again']} run again) " if r.get("run_again") else "")
                   + f"({r['crossings']} crossings, {r['blurry']} blurry)  ({r['reason']})")
    if report.wrote_back:
        click.echo(f"results stored in {report.source.path} (group analysis/)")
    elif report.note:
        click.echo(report.note, err=True)
    directory = report.written[0].parent
    pages = [p for p in report.written if p.parent.name == "cases" and p.name.startswith("<case>")]
    click.echo(f"tables and figures in {directory}/: "
               + ", ".join(p.name for p in report.written if p not in pages))
    if pages:
        count = pages[0].name.partition("(")[2].rstrip(")")
        click.echo(f"case pages ({count}): {pages[0].parent}/<case>.png")
    else:
        click.echo("case pages: none drawn (--case-figures all, flagged or ID,... draws them)")
    damaged = report.damaged
    if damaged:
        fail(f"{report.source.path}: {len(damaged)} damaged case{'s' * (len(damaged) != 1)}, analysed as "
             f"undecided (" + "; ".join(f"{c.case_id}: {c.message}" for c in damaged[:3])
             + (f"; {len(damaged) - 3} more" if len(damaged) > 3 else "") + ")")
