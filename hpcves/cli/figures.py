"""``hpcves shapes`` and ``hpcves animate``: shape sequences and movies of chosen cases."""
from __future__ import annotations

from pathlib import Path

import click

from hpcves.cli.terminal import OneLinePath, StatusLine, clean_errors
from hpcves.files.atomic import check_output_path
from hpcves.model.params import ConfigError
from hpcves.reports.figures import (
    animation_writer,
    check_figure_path,
    choose,
    default_movie,
    parse_where,
    shape_sequence_figure,
    write_animation,
)


@click.command("shapes")
@click.argument("file", type=OneLinePath())
@click.option("--case", "case_ids", multiple=True, metavar="ID", help="A case to draw (repeat for more rows).")
@click.option("--where", "where", multiple=True, metavar="KEY=VALUE",
              help="Draw every case with this parameter value, e.g. --where psi_bar=0.5 (repeatable).")
@click.option("--out", "out", type=OneLinePath(), help="The figure (PNG or PDF; default <file>_shapes.png).")
@click.option("--shapes", "n_shapes", type=click.IntRange(1, 12), default=6, show_default=True,
              help="Shapes per row.")
@click.option("--no-streamlines", is_flag=True, help="Shapes only (faster).")
@clean_errors
def shapes_command(file, case_ids, where, out, n_shapes, no_streamlines):
    """Shape sequences: one row per case, shapes coloured by psi over its last period, with the
    streamlines around them. Choose the rows by --case or --where (sorted by shear rate)."""

    check_output_path(file, new=False)
    if case_ids and where:
        raise ConfigError("--case and --where: choose the cases one way")
    if not case_ids and not where:
        raise ConfigError("choose the cases: --case ID (repeatable) or --where KEY=VALUE, e.g. --where psi_bar=0.5")
    target = Path(out) if out else Path(file).with_name(f"{Path(file).stem}_shapes.png")
    check_output_path(target)
    check_figure_path(target)
    chosen = choose(file, case_ids, parse_where(where))
    fig = shape_sequence_figure(chosen, n_shapes, streamlines=not no_streamlines)
    fig.savefig(target, dpi=130)
    click.echo(f"{target}: {len(chosen)} row{'s' * (len(chosen) != 1)} ("
               + ", ".join(f"{c.case_id} {c.row['regime']}" for c in chosen) + ")")


@click.command("animate")
@click.argument("file", type=OneLinePath())
@click.option("--case", "case_id", metavar="ID", help="The case of a campaign file to animate.")
@click.option("--out", "out", type=OneLinePath(),
              help="The movie: .mp4 (needs ffmpeg) or .gif (default <file>_<case>.mp4, or .gif without ffmpeg).")
@click.option("--fps", type=click.IntRange(1, 60), default=12, show_default=True, help="Frames per second.")
@click.option("--no-streamlines", is_flag=True, help="Shapes only (faster).")
@clean_errors
def animate_command(file, case_id, out, fps, no_streamlines):
    """An animation of one case, one frame per snapshot: the shape coloured by psi with the
    streamlines around it, beside theta(t)."""

    check_output_path(file, new=False)
    if out:
        check_output_path(out)
        animation_writer(Path(out), fps)          # an extension it cannot write: refused before the reading
    chosen = choose(file, (case_id,) if case_id else (), one=True)[0]
    target = Path(out) if out else default_movie(Path(file), chosen.case_id)
    line = StatusLine()
    try:
        frames = write_animation(chosen, target, fps, streamlines=not no_streamlines,
                                 progress=lambda i, n: line.due(0.2) and line.show(f"frame {i}/{n}"))
    finally:
        line.close()
    click.echo(f"{target}: {frames} frames at {fps} per second (case {chosen.case_id}, {chosen.row['regime']})")
    if frames < 2 * fps:
        click.echo(f"  one frame per snapshot: a smoother movie needs a smaller run.snapshot_interval "
                   f"(this case has {frames} snapshots)", err=True)
