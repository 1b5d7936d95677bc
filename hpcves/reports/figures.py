"""Figures drawn on request from a case or campaign file: shape sequences and animations
(``hpcves shapes`` and ``hpcves animate``). Reading and choosing cases lives here; the drawing
is case_figures.py's."""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hpcves.campaign.file import CampaignFile
from hpcves.model.params import ConfigError, Physics
from hpcves.reports.analyze import read_source
from hpcves.run.store import CaseStore, open_file
from hpcves.run.verdict import DAMAGED, PARAMETERS, analyze_case


@dataclass(frozen=True)
class Chosen:
    """One case to draw: what it is, its classification and its snapshots."""

    case_id: str
    parameters: dict
    physics: Physics
    row: dict                  # analysis.analyze_case
    series: dict
    snapshots: dict


def parse_where(items) -> dict:
    """``key=value`` strings -> {parameter: float}; only the four swept parameters."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or key not in PARAMETERS:
            raise ConfigError(f"--where {item!r}: use PARAMETER=VALUE with PARAMETER one of {', '.join(PARAMETERS)}")
        try:
            out[key] = float(value)
        except ValueError:
            raise ConfigError(f"--where {item!r}: {value!r} is not a number") from None
    return out


def choose(path, case_ids=(), where: dict | None = None, one: bool = False) -> list[Chosen]:
    """The cases of ``path`` named in ``case_ids`` (in that order), or all those whose parameters
    match ``where`` (to 1e-9 relative), sorted by shear rate then the other parameters; a
    single-run file is its one case. Damaged cases are refused by name; none chosen is an error.
    ``one``: a single case is wanted, so a campaign file must name it."""
    source = read_source(path)
    if one and not case_ids and source.kind != "case":
        raise ConfigError(f"{path}: a campaign file; name the case with --case ID (hpcves status lists them)")
    by_id = {case.case_id: case for case in source.cases}
    if case_ids:
        unknown = [c for c in case_ids if c not in by_id]
        if unknown:
            raise ConfigError(f"{path}: no case {', '.join(unknown)} (cases: {_range_text(list(by_id))})")
        picked = [by_id[c] for c in case_ids]
    else:
        where = where or {}
        picked = [case for case in source.cases
                  if all(math.isclose(case.parameters[k], v, rel_tol=1e-9, abs_tol=1e-12) for k, v in where.items())]
        picked.sort(key=lambda case: (case.parameters["shear_rate"], *(case.parameters[k] for k in PARAMETERS)))
        if not picked:
            raise ConfigError(f"{path}: no case has " + ", ".join(f"{k} = {v:g}" for k, v in where.items()))
    damaged = [case.case_id for case in picked if case.status == DAMAGED]
    if damaged:
        raise ConfigError(f"{path}: case {', '.join(damaged)} is damaged (hpcves status --check says why)")
    out = []
    with open_file(Path(path), "r", locking=False) as h5:
        campaign = None if source.kind == "case" else CampaignFile(h5)
        for case in picked:
            store = CaseStore(h5) if campaign is None else campaign.store(case.case_id)
            snapshots = store.snapshots()
            if len(snapshots["t"]) == 0:
                raise ConfigError(f"{path}: case {case.case_id} has no snapshots yet")
            out.append(Chosen(case.case_id, case.parameters, store.case.physics,
                              analyze_case(case, source.settings), case.series, snapshots))
    return out


def _range_text(ids: list[str]) -> str:
    return ", ".join(ids) if len(ids) <= 6 else f"{ids[0]} ... {ids[-1]}"


def row_label(chosen: Chosen, varying: list[str]) -> str:
    """``S = 14: PT (T = 3.21)``: what tells one row of a sequence from the others."""
    from hpcves.reports.diagrams import SHORT_NAMES

    keys = varying or ["shear_rate"]
    label = ", ".join(f"{SHORT_NAMES.get(k, k)} = {chosen.parameters[k]:g}" for k in keys)
    regime = chosen.row["regime"]
    period = chosen.row["period"]
    return f"{label}: {regime}" + (f" (T = {period:.3g})" if np.isfinite(period) else "")


def fixed_text(chosen: list[Chosen]) -> tuple[str, list[str]]:
    """(``psi_bar = 0.5, Delta = 0.94, B2 = 0.1``: the parameters all chosen cases share, the
    names of those that vary) -- a figure's title and its rows' labels."""
    from hpcves.reports.analyze import shared_parameters
    from hpcves.reports.diagrams import parameter_text

    same = shared_parameters([c.parameters for c in chosen])
    return parameter_text(same), [k for k in PARAMETERS if len({c.parameters.get(k) for c in chosen}) > 1]


def shape_sequence_figure(chosen: list[Chosen], n_shapes: int = 6, streamlines: bool = True):
    """One row of shapes per chosen case (case_figures.shape_sequences), titled with what they share."""
    from hpcves.reports import case_figures

    title, varying = fixed_text(chosen)
    rows = [(row_label(c, varying), c.snapshots, c.physics, c.row["t_settle"], c.row["period"]) for c in chosen]
    return case_figures.shape_sequences(rows, title=title, n_shapes=n_shapes, streamlines_on=streamlines)


def animation_writer(out: Path, fps: int):
    """The matplotlib writer for ``out``: ffmpeg for .mp4 (refused where ffmpeg is absent),
    pillow for .gif."""
    from matplotlib import animation

    suffix = out.suffix.lower()
    if suffix == ".mp4":
        if not animation.writers.is_available("ffmpeg"):
            raise ConfigError(f"{out}: an mp4 needs ffmpeg, which is not installed here; "
                              "write a .gif instead (pillow), or install ffmpeg")
        return animation.FFMpegWriter(fps=fps, bitrate=2400)
    if suffix == ".gif":
        return animation.PillowWriter(fps=fps)
    raise ConfigError(f"{out}: write an .mp4 (ffmpeg) or a .gif (pillow)")


def check_figure_path(out: Path) -> None:
    """Refuse, before any drawing, a figure file whose extension matplotlib writes no format for."""
    from matplotlib.figure import Figure

    known = Figure().canvas.get_supported_filetypes()
    if out.suffix.lower().lstrip(".") not in known:
        raise ConfigError(f"{out}: matplotlib writes no figure format '{out.suffix or '(none)'}'; use one of "
                          + ", ".join(f".{k}" for k in sorted(known)))


def default_movie(path: Path, case_id: str) -> Path:
    """``<file>_<case>.mp4`` where ffmpeg is installed, else ``.gif``."""
    from matplotlib import animation

    suffix = ".mp4" if animation.writers.is_available("ffmpeg") else ".gif"
    return path.with_name(f"{path.stem}_{case_id}{suffix}")


def write_animation(chosen: Chosen, out: Path, fps: int = 12, streamlines: bool = True, progress=None) -> int:
    """Animate one case into ``out`` (one frame per snapshot); returns the number of frames."""
    from hpcves.reports import case_figures

    writer = animation_writer(out, fps)
    title, _ = fixed_text([chosen])
    regime = chosen.row["regime"]
    fig_title = f"case {chosen.case_id}: {title} -- {regime}"
    fig, movie = case_figures.animation(chosen.series, chosen.snapshots, chosen.physics if streamlines else None,
                                        fig_title)
    frames = len(chosen.snapshots["t"])
    callback = None if progress is None else (lambda i, n: progress(i + 1, n))
    partial = out.with_name(out.name + ".partial" + out.suffix)
    try:
        movie.save(partial, writer=writer, progress_callback=callback)
        partial.replace(out)                  # a kill leaves no half-written movie under the name
    finally:
        if partial.exists():
            partial.unlink()
    return frames
