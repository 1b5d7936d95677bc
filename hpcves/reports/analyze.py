"""``hpcves analyze``: a campaign (or single-run) file -> regimes, tables, figures.

The edge around :mod:`hpcves.analysis.regimes`: read every case's time series, classify
it, write the results back into the file (group ``analysis/``, one row per
case, docs/file-format.md) and into ``regimes.csv`` / ``regimes.md`` and
``periods.md``; the figures are drawn by :mod:`hpcves.reports.diagrams` and
:mod:`hpcves.reports.case_figures`.
"""
from __future__ import annotations

import csv
import dataclasses
import json
import math
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hpcves.analysis import accuracy, grids
from hpcves.analysis.pattern import Topology
from hpcves.analysis.regimes import OUTCOMES, AnalysisSettings
from hpcves.campaign.file import FORMAT as CAMPAIGN_FORMAT
from hpcves.campaign.file import CampaignFile
from hpcves.campaign.study import study_from_toml
from hpcves.errors import HpcvesError
from hpcves.files import faults
from hpcves.files.atomic import StorageError, copy_for_change, publish, remove_partial, size_text
from hpcves.files.lock import CampaignLock, real_path
from hpcves.model.params import ADDED_LATER, LABELS, ConfigError
from hpcves.reports import case_pages
from hpcves.reports import refinement as rc
from hpcves.reports.critical import critical_markdown, critical_rows, write_critical_csv
from hpcves.reports.tables import cell, fmt, markdown_table, write_rows
from hpcves.run.store import FORMAT as CASE_FORMAT
from hpcves.run.store import HDF5_ERRORS, STATUS_NAMES, CaseStore, FileFormatError, attr_text, open_file, reading
from hpcves.run.verdict import (
    DAMAGED,
    PARAMETERS,
    STRESS_COLUMNS,
    TOPOLOGY_COLUMNS,
    CaseData,
    analyze_case,
    case_data,
    mark,
)
from hpcves.version import __version__

#: the columns of regimes.csv and of the file's analysis/ group, in order
#: (``*_err``: statistical uncertainty; ``*_dt_err``: discretisation error of the time step; ``*_N_err``:
#: spatial error, of the grid; accuracy.py)
COLUMNS = ("case",) + PARAMETERS + ("status", "t", "t_end", "rtol", "N", "regime", "period", "period_err",
                                     "period_dt_err", "period_N_err", "theta_mean", "theta_mean_err",
                                     "theta_mean_dt_err", "theta_mean_N_err",
                                     "theta_min", "theta_amplitude", "t_settle", "cycles", "pattern_speed",
                                     "theta_drift", "period_crossings", "bending_gap", "bending_gap_err", "flips") \
    + STRESS_COLUMNS + TOPOLOGY_COLUMNS + ("reason",)
TEXT_COLUMNS = ("case", "status", "regime", "reason")


@dataclass(frozen=True)
class Source:
    """What a file holds: a campaign's cases, or the one case of ``hpcves run``."""

    path: Path
    kind: str                  # "campaign" or "case"
    name: str
    sweep_keys: tuple
    settings: AnalysisSettings
    cases: tuple
    mode: str = "grid"         # campaigns: "grid", "search" or "refine"
    toml: str = ""             # campaigns: the campaign file's text
    links: tuple = ()          # chain campaigns: (case, the case it starts from) of every linked case
    chain_along: str = ""      # chain campaigns: the swept key the chains run along
    starts: tuple = ()         # campaigns with [starts]: the name of each case's start, in case order


def _read_case(campaign: CampaignFile, i: int, case_id: str, search: int, swept: dict) -> CaseData:
    """One case's data (the ``i``-th of the index); a case that cannot be read, fails CaseStore.problems
    or whose swept values in the index are not what it ran comes back "damaged"."""
    try:
        store = campaign.store(case_id)
        problems = store.problems() or campaign.swept_disagree(i, store.case)
        if not problems:
            return case_data(store, case_id, search)
        why = "; ".join(problems[:3]) + (f"; {len(problems) - 3} more" if len(problems) > 3 else "")
    except (FileFormatError, *HDF5_ERRORS) as exc:
        why = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    parameters = {k: float(swept.get(k, math.nan)) for k in PARAMETERS}
    return CaseData(case_id, parameters, DAMAGED, math.nan, math.nan, why, {"t": np.zeros(0)}, search, (DAMAGED,))


def chain_along(toml_text: str) -> str:
    """The key of a chain campaign's ``[chain] along`` ("" where the text has none)."""
    try:
        along = tomllib.loads(toml_text).get("chain", {}).get("along", "")
    except (tomllib.TOMLDecodeError, AttributeError):
        return ""
    return along if isinstance(along, str) else ""


def settings_of(toml_text: str, where: str) -> AnalysisSettings:
    """The ``[analysis]`` table of a campaign file's text (defaults where absent)."""
    try:
        table = tomllib.loads(toml_text).get("analysis", {}) if toml_text else {}
    except tomllib.TOMLDecodeError:
        return AnalysisSettings()
    return AnalysisSettings.from_dict(table, where=f"{where}: [analysis]")


def read_source(path) -> Source:
    """Every case of a campaign file, or the case of a single-run file (read without locking).

    A campaign case whose data are damaged comes back with status "damaged" and what is wrong as its
    message (the others are read as usual); a file whose own structure is damaged is refused.
    """
    path = Path(path)
    with open_file(path, "r", locking=False) as h5, reading(str(path)):
        fmt = attr_text(h5.attrs.get("format", ""))
        if fmt not in (CAMPAIGN_FORMAT, CASE_FORMAT):
            raise FileFormatError(f"{path}: not an hpcves campaign or run file (no format attribute)")
        if fmt == CAMPAIGN_FORMAT:
            campaign = CampaignFile.check(h5, str(path))
            index = h5["index"]
            cases = []
            for i, (c, search) in enumerate(zip(campaign.case_ids, campaign.searches_of_cases())):
                swept = {k: index[k][i] for k in campaign.sweep_keys}
                cases.append(_read_case(campaign, i, c, search, swept))
            toml = campaign.stored_text(str(path))
            links = tuple(campaign.chain_links().items())
            starts = ()
            if "start" in campaign.sweep_keys:
                names = campaign.start_names()
                starts = tuple(names[int(i)] if int(i) < len(names) else f"start {int(i)}"
                               for i in index["start"][:len(cases)])
            return Source(path, "campaign", campaign.name, tuple(campaign.sweep_keys),
                          settings_of(toml, str(path)), tuple(cases), campaign.mode, toml, links,
                          chain_along(toml) if links else "", starts)
        store = CaseStore.open(h5, where=str(path))           # a single run (or a clear refusal)
        problems = store.problems()
        if problems:
            raise FileFormatError(f"{path}: damaged ({'; '.join(problems[:3])})")
        return Source(path, "case", path.stem, (), AnalysisSettings(), (case_data(store, path.stem),))


def analyze_source(source: Source, settings: AnalysisSettings | None = None, progress=None) -> list[dict]:
    settings = settings or source.settings
    rows = []
    for i, case in enumerate(source.cases):
        rows.append(analyze_case(case, settings))
        if source.starts:
            rows[-1]["start"] = source.starts[i]
        if progress is not None:
            progress(i + 1, len(source.cases))
    return rows


# ---------------------------------------------------------------------- results back into the file
def write_back(source: Source, rows: list[dict], settings: AnalysisSettings, progress=None) -> str:
    """Store ``rows`` as the file's ``analysis/`` group; "" if done, else why not (nothing is changed then).

    Safe by construction (atomic.py): the group is written into a copy of the file, which then
    replaces it; a kill or a full disk at any moment leaves the file as it was. Only while no
    campaign or run writes the file (its lock, lock.py) and only if no case changed since ``source``
    was read: results of a file that a campaign advanced in the meantime would be stale.
    """
    if any(case.status == DAMAGED for case in source.cases):
        return "it holds damaged cases"
    path = real_path(source.path)
    try:
        guard = CampaignLock(source.path, "hpcves analyze").acquire()
    except HpcvesError as exc:                  # another campaign or run writes it
        return str(exc)
    try:
        changed = _changes(source)
        if changed:
            return f"the file changed while it was analysed ({changed}); analyze it again"
        if progress is not None:
            progress(f"storing the results in a copy of the file ({size_text(path.stat().st_size)})")
        partial = copy_for_change(path, 200 * len(rows) * len(COLUMNS) + 65536, "storing the analysis")
        try:
            with open_file(partial, "r+") as h5:
                _store(h5, rows, settings)
        except (*HDF5_ERRORS, HpcvesError) as exc:
            remove_partial(path)
            return f"cannot write into a copy of it ({str(exc).strip().splitlines()[0]}); the file is unchanged"
        faults.point("analysis-stored")
        try:
            publish(partial, path)
        except OSError as exc:          # e.g. an immutable file (chattr +i): the rename over it is refused
            remove_partial(path)
            return f"cannot replace it ({exc.strerror or exc}); the file is unchanged"
        return ""
    except StorageError as exc:
        return str(exc)
    finally:
        guard.release()


def read_marks(h5, where: str) -> list[tuple]:
    """:func:`mark` of every case of an open campaign or single-run file, in case order."""
    with reading(where):
        if attr_text(h5.attrs.get("format", "")) == CAMPAIGN_FORMAT:
            campaign = CampaignFile.check(h5, where)
            return [mark(campaign.store(c)) for c in campaign.case_ids]
        return [mark(CaseStore.open(h5, where=where))]


def _changes(source: Source) -> str:
    """How the cases of the file differ now from when ``source`` was read ("" if not)."""
    with open_file(source.path, "r", locking=False) as opened:
        now = read_marks(opened, str(source.path))
    if len(now) != len(source.cases):
        return f"{len(source.cases)} cases then, {len(now)} now"
    changed = [(case, new) for case, new in zip(source.cases, now) if case.mark != new]
    if not changed:
        return ""
    case, new = changed[0]
    first = (f"case {case.case_id}: {case.status} at t = {case.t:.4g} when read, now "
             f"{STATUS_NAMES.get(new[0], new[0])} at t = {new[1]:.4g}")
    return first + (f"; {len(changed) - 1} more" if len(changed) > 1 else "")


def _store(h5, rows: list[dict], settings: AnalysisSettings) -> None:
    """Replace the ``analysis/`` group of an open file: one dataset per column (one row per case)."""
    import h5py

    if "analysis" in h5:
        del h5["analysis"]
    group = h5.create_group("analysis")
    group.attrs["hpcves_version"] = __version__
    group.attrs["analysed_at"] = time.strftime("%Y-%m-%d %H:%M:%S")
    group.attrs["settings"] = json.dumps(settings.__dict__)
    text = h5py.string_dtype()
    for column in COLUMNS:
        values = [row[column] for row in rows]
        if column in TEXT_COLUMNS:
            group.create_dataset(column, data=np.array(values, dtype=object), dtype=text)
        else:
            group.create_dataset(column, data=np.array(values, dtype=float))


def read_back(path) -> list[dict]:
    """The rows written by :func:`write_back` (empty if the file was never analysed)."""
    with open_file(path, "r", locking=False) as h5:
        if "analysis" not in h5:
            return []
        group = h5["analysis"]
        columns = {c: group[c][:] for c in COLUMNS if c in group}
    n = len(columns["case"])
    return [{c: (attr_text(v[i]) if c in TEXT_COLUMNS else float(v[i])) for c, v in columns.items()}
            for i in range(n)]


# ---------------------------------------------------------------------- tables
def write_csv(rows: list[dict], path: Path) -> None:
    """regimes.csv: COLUMNS, with the start's name after the parameters where the study has [starts]."""
    columns = COLUMNS
    if rows and "start" in rows[0]:
        at = COLUMNS.index(PARAMETERS[-1]) + 1
        columns = COLUMNS[:at] + ("start",) + COLUMNS[at:]
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(columns)
        for row in rows:
            writer.writerow([cell(row[c]) for c in columns])


def regimes_markdown(source: Source, rows: list[dict]) -> str:
    keys = list(source.sweep_keys) or list(PARAMETERS)
    header = ["case"] + keys + ["regime", "period", "+- stat", "+- dt", "+- N", "mean theta", "+- stat", "+- dt",
                                "+- N", "min theta", "amplitude", "Delta E_b", "+-", "[eta]", "N1", "pattern",
                                "t settle", "evidence"]
    body = [[row["case"]] + [cell(row[k]) for k in keys]
            + [row["regime"], fmt(row["period"], ".6g"), fmt(row["period_err"], ".2g"),
               _dt_cell(row, "period"), _dt_cell(row, "period", "N"), fmt(row["theta_mean"], ".4f"),
               fmt(row["theta_mean_err"], ".2g"), _dt_cell(row, "theta_mean"), _dt_cell(row, "theta_mean", "N"),
               fmt(row["theta_min"], ".4f"), fmt(row["theta_amplitude"], ".3g"),
               fmt(row["bending_gap"], ".4g"), fmt(row["bending_gap_err"], ".2g"),
               stress_cell(row, "intrinsic_viscosity"), stress_cell(row, "normal_stress_coefficient"),
               pattern_cell(row),
               fmt(row["t_settle"], ".4g"), row["reason"]] for row in rows]
    summary = ", ".join(f"{n} {r}" for r, n in regime_counts(rows).items())
    left = (0, len(keys) + 1, header.index("pattern"), len(header) - 1)
    use = grid_use_of(source)
    summary += f".\n\nGrids (N adapting): {grids.use_text(use)}" if len(use) > 1 else ""
    return (f"# Regimes of {source.kind} {source.name!r}\n\n{source.path}: {len(rows)} cases: {summary}.\n\n"
            + markdown_table(header, body, left) + "\n\n" + ERROR_BARS + "\n")


def grid_use_of(source: Source) -> dict[int, tuple[float, float]]:
    """{N: (simulated time, steps)} over every case of ``source`` that records its N (grids.grid_use)."""
    return grids.combined(grids.grid_use(c.series["t"], c.series["N"], c.series.get("step"))
                          for c in source.cases if len(c.series.get("N", ())))


#: what the error columns of the tables mean
ERROR_BARS = ("+- stat: the statistical uncertainty (period: the standard error of the crossings' slope, or "
              "where they are too few the two estimators' fits and their disagreement; mean theta: its drift "
              "and the averaging over whole periods, docs/analysis.md). +- dt: the discretisation error of the "
              "time step, by the rule measured against rtol (hpcves/analysis/accuracy.py, docs/error_rule.md); "
              "n/e: not estimated -- a fixed-step run (rerun with numerics.rtol), or tumbling, for which the rule does "
              "not hold: the tolerance picks the orbit, and a tumbling period was 1 % longer at rtol = 1e-2 "
              "and 1e-3, 0.1 % at 1e-4, than at 1e-5. +- N: the spatial error of the grid, by the rule "
              "measured against the spectral tail of the settled run (docs/spatial_error.md); n/e for tumbling "
              "and for records without the tails. Delta E_b: max - min of the bending energy over a "
              "period of a phase-treading case, averaged over its whole settled periods, +- their standard "
              "error and what the sampling can miss of the extremes (the time step's error not included). "
              "[eta], N1: the intrinsic viscosity Sigma_xy / (S A) and first normal-stress coefficient "
              "(Sigma_xx - Sigma_yy) / (S A) of the vesicle's stresslet (docs/numerics.md, \"Rheology\"), "
              "averaged as theta is, +- statistical + time-step + grid error (docs/stress_error.md).")


def pattern_cell(row: dict) -> str:
    """The topology of a case's settled pattern in words ("" without snapshots)."""
    if not math.isfinite(row.get("soft_domains", math.nan)):
        return ""
    found = Topology(int(row["soft_domains"]), int(row["domains_on_tips"]), bool(row["two_fold"]))
    return found.text() + ("" if row["topology_steady"] else " (most snapshots; it changes)")


def stress_cell(row: dict, quantity: str) -> str:
    """The settled mean of a rheology series +- its whole error bar [the part that dominates]
    (accuracy.error_bar); "" where there is none (not settled, or a file without the series)."""
    if not math.isfinite(row.get(quantity, math.nan)):
        return ""
    error, dominant = accuracy.error_bar(row, quantity)
    return f"{row[quantity]:.5g} +- {error:.1g} [{dominant}]"


def _dt_cell(row: dict, quantity: str, part: str = "dt") -> str:
    """The discretisation error bar of a quantity: of the time step (``part`` "dt") or of the grid ("N")."""
    if not math.isfinite(row[quantity]):
        return ""
    return fmt(row.get(f"{quantity}_{part}_err", math.nan), ".2g") or "n/e"


def period_cell(row: dict | None, tumbling: str = " (TU)", extra: str = "") -> str:
    """A cell of a period table: ``period +- uncertainty [the part that dominates]`` (statistical +
    discretisation, accuracy.error_bar) with ``extra`` and, for a tumbling case, ``tumbling`` after it,
    where the case phase-treads or tumbles; else its regime; "" where there is no case."""
    if row is None:
        return ""
    if row["regime"] in ("PT", "TU") and math.isfinite(row["period"]):
        error, dominant = accuracy.error_bar(row, "period")
        return (f"{row['period']:.4g} +- {error:.1g} [{dominant}]{extra}"
                + (tumbling if row["regime"] == "TU" else ""))
    return row["regime"]


def period_tables(rows: list[dict], row_key: str, col_key: str, others: list[str]) -> list[tuple[dict, str]]:
    """(fixed values of the other swept keys, Markdown table of row_key x col_key) for each combination.

    A cell holds the period +- its uncertainty (statistical + discretisation, accuracy.error_bar) for PT and TU,
    with the part that dominates in brackets; else the regime.
    """
    out = []
    for fixed, subset in facets(rows, others):
        row_values = sorted({row[row_key] for row in subset})
        col_values = sorted({row[col_key] for row in subset})
        cells = {(row[row_key], row[col_key]): row for row in subset}
        body = [[f"{r:g}"] + [period_cell(cells.get((r, c))) for c in col_values] for r in row_values]
        header = [f"{LABELS.get(row_key, row_key)} \\ {LABELS.get(col_key, col_key)}"] + [f"{c:g}" for c in col_values]
        out.append((fixed, markdown_table(header, body)))
    return out


def grid_axes(source: Source, rows: list[dict], axes: tuple[str, str] | None = None) -> tuple[str, str, list[str]]:
    """(x key, y key, other swept keys) for the phase diagrams and period tables.

    Default: shear rate along x, the next swept key along y; only keys with more
    than one value count as swept.
    """
    varied = [k for k in (source.sweep_keys or PARAMETERS) if len({row[k] for row in rows}) > 1]
    if axes:
        for k in axes:
            if k not in PARAMETERS:
                raise ConfigError(f"--axes: {k!r} is not one of {', '.join(PARAMETERS)}")
        x, y = axes
    else:                                  # a start is a facet, never an axis
        ordered = sorted((k for k in varied if k != "start"), key=lambda k: (k != "shear_rate", varied.index(k)))
        if len(ordered) >= 2:
            x, y = ordered[0], ordered[1]
        elif ordered:
            x, y = ordered[0], next(k for k in PARAMETERS if k != ordered[0])
        else:
            x, y = "shear_rate", "psi_bar"
    others = [k for k in varied if k not in (x, y)]
    return x, y, others


def facets(rows: list[dict], others: list[str]):
    """(fixed values, rows) for every combination of the other swept keys."""
    for combo in sorted({tuple(row[k] for k in others) for row in rows}):
        yield dict(zip(others, combo)), [row for row in rows if tuple(row[k] for k in others) == combo]


def facet_suffix(fixed: dict) -> str:
    """``_B20.3``: the fixed values in a file name."""
    return "".join(f"_{LABELS.get(k, k)}{'_' * isinstance(v, str)}{_value(v)}" for k, v in fixed.items())


def shared_parameters(rows: list[dict], axes=()) -> dict:
    """The parameters (other than ``axes``) that every row has the same value of: what a figure
    over ``rows`` holds fixed, for its title and file name -- but not a parameter added later at the
    value every older study ran with (params.ADDED_LATER: lambda = 1), so their titles and names stay."""
    return {k: rows[0][k] for k in PARAMETERS
            if k not in axes and rows and k in rows[0] and len({r[k] for r in rows}) == 1
            and not (k in ADDED_LATER and rows[0][k] == ADDED_LATER[k])}


def facet_label(fixed: dict) -> str:
    """``B2 = 0.3``: the fixed values in a heading or a title."""
    return ", ".join(f"{LABELS.get(k, k)} = {_value(v)}" for k, v in fixed.items())


def _value(v) -> str:
    """A swept value as text: a number to 6 digits, a start by its name."""
    return v if isinstance(v, str) else f"{v:g}"


def regime_counts(rows: list[dict]) -> dict:
    """Number of cases per outcome, in the order TT, PT, TU, undecided, model limit, failed; outcomes
    with none left out."""
    counts = {r: sum(1 for row in rows if row["regime"] == r) for r in OUTCOMES}
    return {r: n for r, n in counts.items() if n}


# ---------------------------------------------------------------------- the whole command
@dataclass(frozen=True)
class Report:
    source: Source
    rows: tuple
    written: tuple             # paths of the tables and figures
    wrote_back: bool
    note: str                  # why the results were not written back, if they were not
    searches: tuple = ()       # search files: the rows of critical_shear.csv
    refinements: tuple = ()    # refine files: the rows of refinement.csv

    def counts(self) -> dict:
        return regime_counts(self.rows)

    @property
    def damaged(self) -> list[CaseData]:
        """Cases whose data could not be read (or contradict themselves); analysed as undecided."""
        return [case for case in self.source.cases if case.status == DAMAGED]


def parse_overrides(items) -> dict:
    """``key=value`` strings (values in TOML syntax) -> a dict for AnalysisSettings."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set {item!r}: use key=value, e.g. --set min_cycles=5")
        try:
            out[key.strip()] = tomllib.loads(f"v = {value.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            raise ConfigError(f"--set {item!r}: {value!r} is not a TOML value") from None
    return out


def analyze(path, out_dir=None, *, overrides: dict | None = None, write_to_file: bool = True,
            case_figures="auto", axes=None, progress=None, streamlines: bool = True, jobs: int = 1,
            markers: bool = False) -> Report:
    """Classify every case of ``path``; write the tables and figures to ``out_dir`` (default:
    ``<file>_analysis`` next to it) and the results back into the file. ``markers``: the cases drawn
    on the figures for a paper too (a search's or refinement's phase diagrams).

    ``case_figures``: whose one-page figures to draw -- "auto" (every case's up to 100 cases, else the first
    100 flagged ones'), True or "all", False or "none", "flagged" (the cases without a regime), or a
    collection of case ids; ``jobs`` processes draw them (:mod:`hpcves.reports.case_pages`)."""

    source = read_source(path)
    if isinstance(case_figures, bool):
        case_figures = "all" if case_figures else "none"
    case_pages.check(case_figures, [c.case_id for c in source.cases])     # a bad selection refused before the work
    settings = source.settings
    if overrides:
        settings = AnalysisSettings.from_dict({**settings.__dict__, **overrides}, where="--set")
    rows = analyze_source(source, settings, progress=None if progress is None else
                          (lambda i, n: progress(f"classified {i}/{n} cases")))
    out = Path(out_dir) if out_dir else source.path.with_name(source.path.stem + "_analysis")
    try:
        written, searches, refinements = _write_outputs(source, rows, out, axes, case_figures, progress,
                                                        streamlines, jobs, markers)
    except OSError as exc:
        where = exc.filename or out
        raise StorageError(f"{where}: cannot write the tables and figures ({exc.strerror or exc}); "
                           f"{source.path} is unchanged") from None
    note = write_back(source, rows, settings, progress) if write_to_file else ""
    wrote_back = write_to_file and not note
    return Report(source, tuple(rows), tuple(written), wrote_back,
                  f"results not written into the file: {note}" if note else "", tuple(searches),
                  tuple(refinements))


@dataclass(frozen=True)
class Findings:
    """What the writers of an analysis draw on: the classified rows and what is derived from them."""

    source: Source
    rows: list
    x_key: str                  # the axes of the phase diagrams
    y_key: str
    others: list                # the other swept keys: one facet per combination
    searches: list              # critical-shear rows (search campaigns)
    refined: list               # RefineOutcome of every refinement (refine campaigns)
    study: object = None        # the Study of a refine or search campaign
    lines: list = ()            # boundaries.csv rows (refine campaigns)
    markers: bool = False       # the cases as markers on the figures for a paper too

    @property
    def diagrams(self) -> bool:
        """Whether there is a plane to draw: a campaign of several cases."""
        return self.source.kind == "campaign" and len(self.rows) > 1


def findings(source: Source, rows: list[dict], axes=None) -> Findings:
    """The critical shear rates of a search, the boundaries of a refinement, the diagram's axes."""
    study, refined, lines = None, [], []
    if source.mode == "refine":
        study, refined = rc.source_outcomes(source, rows)
        lines = rc.boundary_rows(study, refined)
        axes = axes or tuple(sorted(study.refine.axes, key=lambda k: k != "shear_rate"))
    searches = []
    if source.mode == "search":
        study = study_from_toml(source.toml, source=f"{source.path}: campaign_toml")
        searches = critical_rows(source, rows, study)
    x_key, y_key, others = grid_axes(source, rows, axes)
    return Findings(source, rows, x_key, y_key, others, searches, refined, study, lines)


def regime_tables(f: Findings, out: Path) -> list[Path]:
    """regimes.csv and regimes.md: one row per case."""
    write_csv(f.rows, out / "regimes.csv")
    (out / "regimes.md").write_text(regimes_markdown(f.source, f.rows))
    return [out / "regimes.csv", out / "regimes.md"]


def refinement_tables(f: Findings, out: Path) -> list[Path]:
    """refinement.csv / .md (the verdict of every refinement) and boundaries.csv (the polylines)."""
    if not f.refined:
        return []
    write_rows([o.row() for o in f.refined], rc.refinement_columns(f.study), out / "refinement.csv")
    write_rows(f.lines, rc.boundary_columns(f.study), out / "boundaries.csv")
    (out / "refinement.md").write_text(rc.refinement_markdown(f.source.name, f.study, f.refined, f.rows,
                                                              f.source.cases))
    return [out / "refinement.csv", out / "boundaries.csv", out / "refinement.md"]


def critical_shear_tables(f: Findings, out: Path) -> list[Path]:
    """critical_shear.csv / .md: S_C of every search with its bracket (critical_lambda.csv / .md, lambda_C,
    for searches along lambda)."""
    if f.source.mode != "search":
        return []
    settings = f.study.search
    csv_path, md_path = out / f"{settings.stem}.csv", out / f"{settings.stem}.md"
    write_critical_csv(f.searches, csv_path, settings.along)
    md_path.write_text(critical_markdown(f.source.name, f.searches, settings.along))
    return [csv_path, md_path]


def critical_shear_figures(f: Findings, out: Path) -> list[Path]:
    """S_C (lambda_C) against the first parameter the searches vary, one figure per value of the others."""
    from hpcves.reports import diagrams

    if f.source.mode != "search":
        return []
    settings = f.study.search
    varied = [k for k in f.source.sweep_keys if k != settings.along and len({r[k] for r in f.searches}) > 1]
    written = []
    for fixed, subset in (facets(f.searches, varied[1:]) if varied else ()):
        fig = diagrams.critical_shear_figure(subset, varied[0], title=diagrams.parameter_text(
            shared_parameters(subset, (varied[0], settings.along))), along=settings.along)
        written += _save(fig, out / f"{settings.stem}{facet_suffix(fixed)}")
    return written


def period_table(f: Findings, out: Path) -> list[Path]:
    """periods.md: the period (or regime) of every case of a grid, one table per facet."""
    if not (f.diagrams and f.source.mode == "grid"):
        return []
    text = [f"# Periods of {f.source.name!r}\n\nPeriod of theta +- its uncertainty where the case "
            "phase-treads (PT) or tumbles (TU); otherwise its regime. The uncertainty is the statistical "
            "one plus the discretisation errors of the time step and of the grid; in brackets the one that "
            "dominates (stat, dt or N; dt n/e: not estimated, for a fixed-step run or a tumbling case -- a "
            "tumbling period can be 1 % off at rtol >= 1e-3, docs/error_rule.md; N n/e: for a tumbling case, "
            "a record without the spectral tails or one beyond the watch's 3e-3, docs/spatial_error.md). "
            "regimes.md has each part.\n"]
    for fixed, table in period_tables(f.rows, f.y_key, f.x_key, f.others):
        if fixed:
            text.append(f"## {facet_label(fixed)}\n")
        text.append(table + "\n")
    (out / "periods.md").write_text("\n".join(text))
    return [out / "periods.md"]


def phase_diagrams(f: Findings, out: Path) -> list[Path]:
    """The regimes over the plane, one per facet (a point drawn by its last run). A grid: every case
    drawn over the regions its cases decide, and the periods against its rows. A search or a
    refinement: the figure for a paper (diagrams.paper_diagram: the decided regions filled, the critical
    values or the traced boundaries through the white between them, a journal column wide; the cases
    as markers with ``f.markers``), and ``phase_diagram*_cases``, every case drawn with the critical
    rates or the boundaries over them."""
    from hpcves.analysis.refine import regions as refined_regions
    from hpcves.reports import diagrams

    if not f.diagrams:
        return []
    written = []
    repeated = rc.superseded(f.source)          # a refinement's runs that a later run of their point repeats
    for fixed, subset in facets([r for r in f.rows if r["case"] not in repeated], f.others):
        suffix = facet_suffix(fixed)
        title = diagrams.parameter_text(shared_parameters(subset, (f.x_key, f.y_key)))
        mine = lambda rows: [r for r in rows if all(r[k] == v for k, v in fixed.items() if k in r)]  # noqa: E731
        regions = None
        if f.refined and {f.x_key, f.y_key} == set(f.study.refine.axes):
            regions = [region for o in f.refined if all(o.point.get(k, v) == v for k, v in fixed.items())
                       for region in _oriented(refined_regions(o.settings, o.regimes), o.settings, f.x_key)]
        fig = diagrams.phase_diagram(subset, f.x_key, f.y_key, title=title, annotate_periods=f.source.mode == "grid",
                                     regions=regions,
                                     log_keys=f.study.refine_settings.log_keys() if f.refined else None)
        along = f.study.search.along if f.searches else None
        if f.searches and along in (f.x_key, f.y_key):
            diagrams.mark_critical(fig.axes[0], mine(f.searches), f.y_key if f.x_key == along else f.x_key,
                                   s_on_x=f.x_key == along, along=along)
        if regions is not None:
            diagrams.mark_boundaries(fig.axes[0], mine(f.lines), f.x_key, f.y_key)      # a start: every one's
        if f.source.mode == "grid":
            written += _save(fig, out / f"phase_diagram{suffix}")
            cells = len({r[f.x_key] for r in subset}) * len({r[f.y_key] for r in subset})
            if cells <= MAX_PERIOD_CELLS:
                written += _save(diagrams.period_figure(subset, f.y_key, f.x_key, title=title),
                                 out / f"periods{suffix}")
            continue
        written += _save(fig, out / f"phase_diagram{suffix}_cases")
        paper = _paper_figure(f, subset, mine, regions, title)
        if paper is not None:
            written += _save(paper, out / f"phase_diagram{suffix}", dpi=300)
    return written


def stress_figures(f: Findings, out: Path) -> list[Path]:
    """The vesicles' stress over the plane (diagrams.stress_diagram: ``intrinsic_viscosity{suffix}`` and
    ``normal_stress{suffix}``, a colour map under the cases), or, where one parameter alone is swept,
    [eta] and N1 against it (diagrams.stress_curves: ``stress{suffix}``); nothing where no case has them
    (files of case format 6 and before)."""
    from hpcves.reports import diagrams

    if not f.diagrams or not any(math.isfinite(r.get("intrinsic_viscosity", math.nan)) for r in f.rows):
        return []
    written = []
    repeated = rc.superseded(f.source)
    plane = len({r[f.y_key] for r in f.rows}) > 1
    log_keys = f.study.refine_settings.log_keys() if f.refined else None
    for fixed, subset in facets([r for r in f.rows if r["case"] not in repeated], f.others):
        suffix = facet_suffix(fixed)
        if not plane:
            title = diagrams.parameter_text(shared_parameters(subset, (f.x_key,)))
            written += _save(diagrams.stress_curves(subset, f.x_key, title=title, log_keys=log_keys),
                             out / f"stress{suffix}")
            continue
        title = diagrams.parameter_text(shared_parameters(subset, (f.x_key, f.y_key)))
        for quantity, stem in (("intrinsic_viscosity", "intrinsic_viscosity"), ("normal_stress_coefficient",
                                                                                 "normal_stress")):
            written += _save(diagrams.stress_diagram(subset, f.x_key, f.y_key, quantity, title=title,
                                                     log_keys=log_keys), out / f"{stem}{suffix}")
    return written


def _oriented(regions, settings, x_key: str):
    """A refinement's regions with x the diagram's x (its axes may be the other way round)."""
    if settings.x.key == x_key:
        return regions
    return [((y0, y1, x0, x1), regime) for (x0, x1, y0, y1), regime in regions]


def _paper_figure(f: Findings, subset: list[dict], mine, regions, title: str):
    """diagrams.paper_diagram of a search's or a refinement's facet (None: its plane is not the one searched
    or refined)."""
    from hpcves.reports import diagrams

    log_keys = set(diagrams.LOG_KEYS) | (set(f.study.refine_settings.log_keys()) if f.refined else set())
    if regions is not None:
        lines = {}
        for r in sorted(mine(f.lines), key=lambda r: (r["line"], r["order"])):
            lines.setdefault(r["line"], []).append((r[f.x_key], r[f.y_key]))
        return diagrams.paper_diagram(subset, f.x_key, f.y_key, regions, lines=list(lines.values()),
                                      markers=f.markers, log_keys=log_keys, title=title)
    along = f.study.search.along if f.searches else None
    if along not in (f.x_key, f.y_key):
        return None
    other = f.y_key if f.x_key == along else f.x_key
    column = f.study.search.column
    place = (lambda v, y: (v, y)) if f.x_key == along else (lambda v, y: (y, v))     # noqa: E731
    converged = sorted((r for r in mine(f.searches) if np.isfinite(r[column])), key=lambda r: r[other])
    brackets = [(place(r["bracket_low"], r[other]), place(r["bracket_high"], r[other])) for r in converged]
    line = [place(r[column], r[other]) for r in converged]
    return diagrams.paper_diagram(subset, f.x_key, f.y_key, diagrams.decided_regions(subset, f.x_key, f.y_key),
                                  lines=[line] if len(line) > 1 else [], brackets=brackets, markers=f.markers,
                                  log_keys=log_keys, title=title)


#: the period figure (a table drawn cell by cell, 1.6 x 0.8 inches a cell) is drawn up to this many cells;
#: a grid of 200 x 10 made a 322-inch figure that took 3 GB to render (periods.md holds every value)
MAX_PERIOD_CELLS = 400


#: how a chain's legs are named, by the key it runs along
LEG_NAMES = {"shear_rate": "S", "excess_length": "Delta", "psi_bar": "psi_bar", "B2": "B2", "viscosity_ratio": "lambda"}


def run_labels(source: Source, rows: list[dict]) -> list[str]:
    """Where each row's run came from, in words: its start's name ([starts]) and, in a chain campaign,
    its leg -- "<key> up" for a case run at a larger value than the one before, "<key> down" for a
    smaller one, the first case of a chain on the leg of the case after it; "" where the campaign has
    neither."""
    legs = [""] * len(rows)
    if source.links and source.chain_along:
        key, before = source.chain_along, dict(source.links)
        after = {b: c for c, b in before.items()}
        name = LEG_NAMES.get(key, key)
        by_id = {r["case"]: r for r in rows}

        def leg(case_id):
            previous, here = by_id.get(before.get(case_id, "")), by_id.get(case_id)
            if previous is None:                       # the first of its chain: the way it goes on
                following = by_id.get(after.get(case_id, ""))
                return "up" if following is None or following[key] > here[key] else "down"
            return "down" if here[key] < previous[key] else "up"

        for i, r in enumerate(rows):
            legs[i] = f"{name} {leg(r['case'])}"
    starts = [r.get("start", "") for r in rows]
    return [" ".join(part for part in (s, leg) if part) for s, leg in zip(starts, legs)]


def attractor_maps(f: Findings, out: Path) -> list[Path]:
    """A campaign whose points were run more than once -- from several [starts], or on both legs of a
    chain: each point's runs grouped into attractors (attractors.md, attractors.png per facet), and for
    a chain its two legs side by side (continuation.png per start and facet: hysteresis)."""
    from hpcves.reports import attractor_map

    labels = run_labels(f.source, f.rows)
    names = tuple(dict.fromkeys(labels))
    if len(names) < 2:
        return []
    by_label = {name: [r for r, label in zip(f.rows, labels) if label == name] for name in names}
    compared = attractor_map.compare(by_label)
    others = [k for k in f.others if k != "start"]
    several = [c for c in compared if len(c["attractors"]) > 1]
    chain = f"; a chain's case starts from the end of the one before it along {f.source.chain_along} " \
            "(up: the first and those at a larger value than the one before; down: on the way back)" \
        if f.source.links else ""
    text = [f"# Attractors of {f.source.name!r}\n",
            f"Every point was run {len(names)} ways ({', '.join(names)}{chain}). The runs of a point are "
            "grouped into attractors: the same regime and pattern topology, theta and period within their "
            "error bars (docs/analysis.md). Where a point has more than one, stable states coexist there, "
            "and which one a run settles on depends on where it came from.\n",
            attractor_map.summary(compared, names) + "\n"]
    if several:
        text.append(f"## Points with more than one attractor ({len(several)})\n")
        body = [[cell(c[k]) for k in (f.x_key, f.y_key, *others)]
                + ["; ".join(a.text() for a in c["attractors"])] for c in several]
        text.append(markdown_table([f.x_key, f.y_key, *others, "attractors (and the runs that reached each)"],
                                   body) + "\n")
    (out / "attractors.md").write_text("\n".join(text))
    written = [out / "attractors.md"]
    for fixed, subset in facets(compared, others):
        title = f"{f.source.name}: attractors of {len(names)} runs a point" + (
            f" ({facet_label(fixed)})" if fixed else "")
        lines = None                # the borders of coexistence, where a refinement of attractors traced them
        if f.refined and f.study.refine.attractors and {f.x_key, f.y_key} == set(f.study.refine.axes):
            lines = [r for r in f.lines if all(r[k] == v for k, v in fixed.items() if k in r)]
        fig = attractor_map.attractors_figure(subset, f.x_key, f.y_key, title=title, lines=lines)
        written += _save(fig, out / f"attractors{facet_suffix(fixed)}")
    if f.source.links:
        written += _continuation_figures(f, labels, others, out)
    return written


def _continuation_figures(f: Findings, labels: list[str], others: list[str], out: Path) -> list[Path]:
    """continuation.png per facet of the keys other than the chained one: the settled inclination and
    period against the chained key, a line per start and leg (hysteresis)."""
    from hpcves.reports import attractor_map

    key = f.source.chain_along
    rest = [k for k in f.source.sweep_keys if k not in (key, "start") and len({r[k] for r in f.rows}) > 1]
    labelled = [{**r, "_label": label} for r, label in zip(f.rows, labels)]
    by_id, before = {r["case"]: r for r in labelled}, dict(f.source.links)
    written = []
    for fixed, subset in facets(labelled, rest):
        runs, joins = {}, {}
        for r in sorted(subset, key=lambda r: r["case"]):          # cases are numbered in chain order
            runs.setdefault(r["_label"], []).append(r)
        for label, rows in runs.items():           # a leg's line starts where the chain turned into it
            turn = by_id.get(before.get(rows[0]["case"], ""))
            if turn is not None:
                joins[label] = turn
        title = f"{f.source.name}: continuation along {key}" + (f" ({facet_label(fixed)})" if fixed else "")
        written += _save(attractor_map.hysteresis_figure(runs, key, title=title, joins=joins),
                         out / f"continuation{facet_suffix(fixed)}")
    return written


#: the writers of an analysis, in the order they run: each writes its artefacts (or none) into the
#: output folder and returns their paths
WRITERS = (regime_tables, refinement_tables, critical_shear_tables, critical_shear_figures, period_table,
           phase_diagrams, stress_figures, attractor_maps)


def _write_outputs(source: Source, rows: list[dict], out: Path, axes, case_figures, progress,
                   streamlines: bool = True, jobs: int = 1, markers: bool = False):
    """The tables and figures of an analysis into ``out`` (every writer of WRITERS, then the case
    pages asked for): (paths written, critical_shear rows, refinement rows)."""
    out.mkdir(parents=True, exist_ok=True)
    found = dataclasses.replace(findings(source, rows, axes), markers=markers)
    written = [path for writer in WRITERS for path in writer(found, out)]
    pages = {r["case"] for r in case_pages.chosen(rows, case_figures)}
    if pages:
        live = [r for r, case in zip(rows, source.cases) if case.status != DAMAGED and r["case"] in pages]
        case_pages.draw_pages(source.path, source.kind == "campaign", live, out / "cases", streamlines=streamlines,
                              jobs=jobs, progress=progress)
        written.append(out / "cases" / f"<case>.png ({len(live)})")
    return written, found.searches, [o.row() for o in found.refined]


def _save(fig, stem: Path, dpi: int = 150) -> list[Path]:
    """Save a figure as PNG (at ``dpi``) and PDF (vector)."""
    paths = [stem.with_name(f"{stem.name}.{ext}") for ext in ("png", "pdf")]
    for path in paths:
        fig.savefig(path, dpi=dpi)
    return paths


