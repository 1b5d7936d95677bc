"""``hpcves status``: a campaign file's cases, totals and what is left, as a table or JSON."""
from __future__ import annotations

import json
import math
import sys
from collections import Counter

import click

from hpcves.campaign.file import BeingCreated, CreationInterrupted, read_table
from hpcves.campaign.progress import WORK_LEFT, progress
from hpcves.cli.refuse import refuse_a_study_file
from hpcves.cli.terminal import OneLinePath, clean_errors, duration, error, fail
from hpcves.files.atomic import check_output_path
from hpcves.run.store import ENDED_NAMES
from hpcves.run.verdict import DAMAGED


@click.command("status")
@click.argument("campaign_file", type=OneLinePath())
@click.option("--check", is_flag=True,
              help="Also check every dataset of every case (shapes, counters, checkpoints), as --resume does: "
                   "about 3 ms a case instead of 0.2.")
@click.option("--json", "as_json", is_flag=True,
              help="One JSON object on stdout instead of the table: the cases, the totals and what is left.")
@clean_errors
def status_command(campaign_file, check, as_json):
    """One line per case of a campaign file (it may be running), the totals and what is left.

    Exit status: 0 the campaign is complete (nothing left for --resume); 1 complete, but cases
    failed (--resume --retry-failed reruns them); 3 work is left (cases to run, the next stage of
    a search or refinement, a campaign writing the file, or a creation that was cut short:
    resubmit); 2 the file cannot be read or a case is damaged.
    """
    check_output_path(campaign_file, new=False)
    refuse_a_study_file(campaign_file, "status")
    try:
        table = read_table(campaign_file, check=check)
    except (BeingCreated, CreationInterrupted) as exc:        # work left: a campaign makes it, or --resume will
        if as_json:
            click.echo(json.dumps({"file": str(campaign_file), "complete": False, "left": str(exc),
                                   "exit_status": WORK_LEFT}))
        elif isinstance(exc, CreationInterrupted):
            error(exc)
        else:
            click.echo(str(exc))
        sys.exit(WORK_LEFT)
    name, rows = table.name, table.rows
    writing = (f"a campaign is writing it ({table.writer})" if table.writer else "no campaign is writing it")
    damaged = [r for r in rows if r["status"] == DAMAGED]
    left = None if damaged else progress(campaign_file, rows, table.writer)
    totals = Counter(r["status"] for r in rows)            # status -> cases, in the order first seen
    if as_json:
        _status_json(campaign_file, table, totals, left)
    elif not rows:
        click.echo(f"{campaign_file}: study {name!r}, no cases; {writing}")
    else:
        _status_table(name, rows, totals, writing, left)
    if damaged:
        fail(f"{campaign_file}: {len(damaged)} damaged case{'s' * (len(damaged) != 1)} ("
             + "; ".join(f"{r['case']}: {r['message']}" for r in damaged[:3])
             + (f"; {len(damaged) - 3} more" if len(damaged) > 3 else "") + ")")
    sys.exit(left.exit_status)


def _status_json(campaign_file, table, totals, left) -> None:
    """``hpcves status --json``: the file, the study, every case, the totals and what is left."""
    def plain(value):                       # JSON has no NaN: null
        return None if isinstance(value, float) and not math.isfinite(value) else value
    click.echo(json.dumps({
        "file": str(campaign_file), "study": table.name, "writer": table.writer, "cases": len(table.rows),
        "totals": dict(totals), "complete": None if left is None else left.complete,
        "left": "damaged cases" if left is None else left.left, "failed": totals.get("failed", 0),
        "exit_status": 2 if left is None else left.exit_status,
        "rows": [{k: plain(v) for k, v in r.items()} for r in table.rows]}, indent=1))


def _status_table(name, rows, totals, writing, left) -> None:
    """The human ``hpcves status``: one line per case, the totals, what is left."""
    keys = [k for k in rows[0] if k not in ("case", "status", "t", "t_end", "wall", "steps_per_second",
                                            "message")]
    header = ["case", *keys, "status", "t / t_end", "wall", "steps/s", "reason"]
    lines = []
    for r in rows:
        lines.append([r["case"], *(f"{r[k]:g}" if isinstance(r[k], float) else r[k] or "-" for k in keys), r["status"],
                      f"{r['t']:.4g} / {r['t_end']:.4g}",
                      duration(r["wall"]) if r["wall"] > 0 else "-",
                      f"{r['steps_per_second']:,.0f}" if r["steps_per_second"] > 0 else "-",
                      (r["message"].splitlines() or [""])[0][:80]])
    widths = [max(len(str(x)) for x in column) for column in zip(header, *lines)]
    for line in [header, *lines]:
        click.echo("  ".join(str(x).ljust(w) for x, w in zip(line, widths)).rstrip())
    readable = [r for r in rows if r["status"] != DAMAGED]
    # a case that ended (finished, decided early, failed, at the model's limit) has done its share, whatever its t
    done = sum(r["t_end"] if r["status"] in ENDED_NAMES else min(r["t"], r["t_end"]) for r in readable)
    total = sum(r["t_end"] for r in readable)
    wall = sum(r["wall"] for r in readable)
    early = sum(1 for r in readable if r["status"] in ENDED_NAMES and r["t"] < r["t_end"])
    share = (f"{100 * done / total:.0f} % done" if total > 0 else "- done") + (
        f" ({early} case{'s' * (early != 1)} ended before t_end: decided, failed or at the model's limit)"
        if early else "")
    if left is None:
        state = ""
    elif left.complete:
        state = "; complete" + (f", {left.failed} failed (--resume --retry-failed reruns them)" if left.failed else "")
    else:
        state = f"; work left: {left.left}"
    click.echo(f"study {name!r}: {len(rows)} cases: " + ", ".join(f"{n} {s}" for s, n in totals.items())
               + f"; simulated time {share}; {duration(wall)} of compute; {writing}{state}")
