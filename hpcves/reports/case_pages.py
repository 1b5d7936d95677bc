"""The one-page figure of each case (``cases/<id>.png`` of ``hpcves analyze``), drawn by a pool of processes.

A page costs about 1 s of matplotlib (1.2 s measured on 79 pages of a refined campaign, 2 s more
with the streamlines), so a campaign of a thousand cases spends far longer on its pages than on its
classification. Two ways to spend less: ``which`` draws the pages of some cases only ("flagged":
those that ended without a regime -- undecided, failed, stopped at a model limit, unfinished, damaged
-- which are the ones a person opens), and ``jobs`` draws them in that many processes (each opens the
file for reading on its own; matplotlib's Agg canvas is not shared between threads, so processes).
"""
from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Collection
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from hpcves.campaign.file import CampaignFile
from hpcves.model.params import ConfigError
from hpcves.run.store import CaseStore, open_file

#: ``which`` of the named selections
SELECTIONS = ("auto", "all", "flagged", "none")
#: "auto": every case's page up to this many cases; beyond, the flagged ones', at most this many (at ~1-3 s
#: a page, "all" of a 2000-case grid would draw for an hour and more)
AUTO_PAGES = 100
#: regimes that say the case is decided; any other outcome (undecided, failed, ...) is flagged
DECIDED = ("TT", "PT", "TU")
#: the fields of a regimes.csv row a page shows
ROW_FIELDS = ("regime", "t_settle", "period", "reason")


def flagged(row: dict) -> bool:
    """Whether a case's page is among the "flagged": not finished, or finished without a regime."""
    return row["status"] != "finished" or row["regime"] not in DECIDED


def chosen(rows: list[dict], which: str | Collection[str]) -> list[dict]:
    """The rows whose pages ``which`` asks for: "auto" (every case's up to AUTO_PAGES cases, else the first
    AUTO_PAGES flagged ones'), "all", "flagged", "none", or a collection of case ids (an id that is no case
    of the file is an error: a page asked for by name should not silently vanish)."""
    check(which, [r["case"] for r in rows])
    if isinstance(which, str):
        if which == "auto":
            return list(rows) if len(rows) <= AUTO_PAGES else [r for r in rows if flagged(r)][:AUTO_PAGES]
        return list(rows) if which == "all" else [r for r in rows if flagged(r)] if which == "flagged" else []
    wanted = set(which)
    return [r for r in rows if r["case"] in wanted]


def check(which: str | Collection[str], case_ids: list[str]) -> None:
    """Refuse a selection that is none of SELECTIONS, or names a case that is not among ``case_ids``."""
    if isinstance(which, str):
        if which not in SELECTIONS:
            raise ConfigError(f"case figures: {which!r} is none of {', '.join(SELECTIONS)} (nor a list of case ids)")
        return
    missing = set(which) - set(case_ids)
    if missing:
        raise ConfigError(f"case figures: no case {', '.join(sorted(missing))} in the file "
                          f"(ask for {', '.join(SELECTIONS)} or case ids such as "
                          f"{case_ids[0] if case_ids else '0001'})")


def draw_page(path: str, case_id: str | None, row: dict, streamlines: bool, target: str) -> str:
    """Draw the page of case ``case_id`` of the campaign file ``path`` (None: the case of a single-run
    file) with its classification ``row`` into ``target``; returns ``target``."""
    from hpcves.reports import case_figures

    with open_file(path, "r", locking=False) as h5:
        store = CaseStore(h5) if case_id is None else CampaignFile(h5).store(case_id)
        title = (f"case {case_id}: " if case_id is not None else "") \
            + case_figures.case_title(dict(store.attrs)) + f" -- {row['regime']}"
        fig = case_figures.case_figure(store.timeseries(), store.snapshots(), title=title, kymographs=True,
                                       t_settle=row["t_settle"], period=row["period"],
                                       physics=store.case.physics if streamlines else None,
                                       subtitle=brief(row["reason"]))
    fig.savefig(target, dpi=90)
    return target


def draw_pages(path: Path, campaign: bool, rows: list[dict], directory: Path, *, streamlines: bool = True,
               jobs: int = 1, progress: Callable[[str], None] | None = None) -> list[Path]:
    """The pages of ``rows`` (regimes.csv rows of the file ``path``) as ``directory/<case>.png``,
    drawn by ``jobs`` processes (1: here); the paths, in the order of ``rows``."""
    directory.mkdir(parents=True, exist_ok=True)
    tasks = [(str(path), r["case"] if campaign else None, {k: r[k] for k in ROW_FIELDS}, streamlines,
              str(directory / f"{r['case']}.png")) for r in rows]
    done = 0

    def tick():
        nonlocal done
        done += 1
        if progress is not None:
            progress(f"case figures {done}/{len(tasks)}")

    if jobs <= 1 or len(tasks) <= 1:
        for task in tasks:
            draw_page(*task)
            tick()
    else:     # spawn: a fresh interpreter per worker, no HDF5 handle or lock inherited from this one
        workers = min(jobs, len(tasks))
        # chunks of up to 4 pages (fewer messages), but at least two chunks per worker, so that a
        # few pages are shared out evenly (6 pages in chunks of 4 left one worker 4 and the other 2)
        chunk = max(1, min(4, len(tasks) // (2 * workers)))
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            for _ in pool.map(draw_page, *zip(*tasks), chunksize=chunk):
                tick()
    return [Path(task[-1]) for task in tasks]


def brief(text: str, width: int = 120) -> str:
    """The first clause of a reason, clipped to ``width`` characters: a figure's subtitle."""
    first = text.split("; ")[0]
    return first if len(first) <= width else first[: width - 3].rstrip() + "..."
