"""``hpcves analyze``: a campaign (or single-run) file -> regimes, tables, figures.

The edge around :mod:`hpcves.regimes`: read every case's time series, classify
it, write the results back into the file (group ``analysis/``, one row per
case, docs/file-format.md) and into ``regimes.csv`` / ``regimes.md`` and
``periods.md``; the figures are drawn by :mod:`hpcves.plots`.
"""
from __future__ import annotations

import csv
import json
import math
import time
import tomllib
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from . import __version__
from .campaign_file import FORMAT as CAMPAIGN_FORMAT
from .campaign_file import CampaignFile
from .checkpoint import FAILED, FINISHED, STATUS_NAMES, CaseStore, FileFormatError, attr_text, open_file
from .params import ConfigError
from .regimes import REGIMES, UNDECIDED, AnalysisSettings, Classification, classify

PARAMETERS = ("shear_rate", "psi_bar", "excess_length", "B2")
#: the columns of regimes.csv and of the file's analysis/ group, in order
COLUMNS = ("case",) + PARAMETERS + ("status", "t", "t_end", "regime", "period", "period_err", "theta_mean",
                                     "theta_min", "theta_amplitude", "t_settle", "cycles", "pattern_speed",
                                     "theta_drift", "period_crossings", "reason")
TEXT_COLUMNS = ("case", "status", "regime", "reason")


@dataclass(frozen=True)
class CaseData:
    case_id: str
    parameters: dict           # the four sweepable physics parameters
    status: str
    t: float                   # reached
    t_end: float
    message: str
    series: dict
    search: int = -1           # search files: the search the case belongs to


@dataclass(frozen=True)
class Source:
    """What a file holds: a campaign's cases, or the one case of ``hpcves run``."""

    path: Path
    kind: str                  # "campaign" or "case"
    name: str
    sweep_keys: tuple
    settings: AnalysisSettings
    cases: tuple
    mode: str = "grid"         # campaigns: "grid" or "search"
    toml: str = ""             # campaigns: the campaign file's text


def case_data(store: CaseStore, case_id: str, search: int = -1) -> CaseData:
    attrs = store.group.attrs
    t, t_end = (float(v) for v in store.progress[:2])
    return CaseData(case_id, {k: float(attrs[f"physics.{k}"]) for k in PARAMETERS},
                    STATUS_NAMES.get(store.status, str(store.status)), t, t_end, store.message, store.timeseries(),
                    search)


def settings_of(toml_text: str, where: str) -> AnalysisSettings:
    """The ``[analysis]`` table of a campaign file's text (defaults where absent)."""
    try:
        table = tomllib.loads(toml_text).get("analysis", {}) if toml_text else {}
    except tomllib.TOMLDecodeError:
        return AnalysisSettings()
    return AnalysisSettings.from_dict(table, where=f"{where}: [analysis]")


def read_source(path) -> Source:
    """Every case of a campaign file, or the case of a single-run file (read without locking)."""
    path = Path(path)
    with open_file(path, "r", locking=False) as h5:
        fmt = attr_text(h5.attrs.get("format", ""))
        try:
            if fmt == CAMPAIGN_FORMAT:
                campaign = CampaignFile.check(h5, str(path))
                cases = tuple(case_data(campaign.store(c), c, search)
                              for c, search in zip(campaign.case_ids, campaign.searches_of_cases()))
                toml = attr_text(h5.attrs.get("campaign_toml", ""))
                return Source(path, "campaign", campaign.name, tuple(campaign.sweep_keys),
                              settings_of(toml, str(path)), cases, campaign.mode, toml)
            store = CaseStore.open(h5, where=str(path))       # a single run (or a clear refusal)
            return Source(path, "case", path.stem, (), AnalysisSettings(), (case_data(store, path.stem),))
        except (KeyError, ValueError, OSError) as exc:
            raise FileFormatError(f"{path}: damaged file ({type(exc).__name__}: {exc})") from None


def analyse_case(case: CaseData, settings: AnalysisSettings) -> dict:
    """One row of regimes.csv (COLUMNS) for one case."""
    base = {"case": case.case_id, **case.parameters, "status": case.status, "t": case.t, "t_end": case.t_end}
    n = len(case.series["t"])
    if case.status == STATUS_NAMES[FAILED] or n == 0:
        first = case.message.splitlines()[0] if case.message else ""
        reason = f"case failed: {first}" if case.status == STATUS_NAMES[FAILED] else "not run yet"
        empty = Classification(UNDECIDED, reason, *([math.nan] * (len(fields(Classification)) - 2)))
        return {**base, **empty.row()}
    found = classify(case.series, settings)
    if case.status != STATUS_NAMES[FINISHED]:
        found = replace(found, reason=f"{case.status} at t = {case.t:.4g} of {case.t_end:.4g}: {found.reason}")
    return {**base, **found.row()}


def analyse_source(source: Source, settings: AnalysisSettings | None = None, progress=None) -> list[dict]:
    settings = settings or source.settings
    rows = []
    for i, case in enumerate(source.cases):
        rows.append(analyse_case(case, settings))
        if progress is not None:
            progress(i + 1, len(source.cases))
    return rows


# ---------------------------------------------------------------------- results back into the file
def write_back(path, rows: list[dict], settings: AnalysisSettings) -> None:
    """Replace the file's ``analysis/`` group: one dataset per column (one row per case)."""
    import h5py

    with open_file(path, "r+") as h5:
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
def _cell(value, column: str) -> str:
    if column in TEXT_COLUMNS:
        return str(value)
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return ""
    return f"{value:.6g}"


def write_csv(rows: list[dict], path: Path) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(COLUMNS)
        for row in rows:
            writer.writerow([_cell(row[c], c) for c in COLUMNS])


def markdown_table(header: list[str], body: list[list[str]], left: tuple = (0,)) -> str:
    """A Markdown table; the columns numbered in ``left`` are left-aligned, the others right-aligned."""
    lines = ["| " + " | ".join(header) + " |",
             "| " + " | ".join("---" if i in left else "---:" for i in range(len(header))) + " |"]
    lines += ["| " + " | ".join(cell.replace("|", "/") for cell in row) + " |" for row in body]
    return "\n".join(lines)


def regimes_markdown(source: Source, rows: list[dict]) -> str:
    keys = list(source.sweep_keys) or list(PARAMETERS)
    header = ["case"] + keys + ["regime", "period", "+-", "mean theta", "min theta", "amplitude", "t settle",
                                "evidence"]
    body = [[row["case"]] + [_cell(row[k], k) for k in keys]
            + [row["regime"], _fmt(row["period"], ".6g"), _fmt(row["period_err"], ".2g"),
               _fmt(row["theta_mean"], ".4f"), _fmt(row["theta_min"], ".4f"), _fmt(row["theta_amplitude"], ".3g"),
               _fmt(row["t_settle"], ".4g"), row["reason"]] for row in rows]
    summary = ", ".join(f"{n} {r}" for r, n in regime_counts(rows).items())
    left = (0, len(keys) + 1, len(header) - 1)
    return (f"# Regimes of {source.kind} {source.name!r}\n\n{source.path}: {len(rows)} cases: {summary}.\n\n"
            + markdown_table(header, body, left) + "\n")


def _fmt(value: float, spec: str) -> str:
    return format(value, spec) if isinstance(value, float) and math.isfinite(value) else ""


def period_tables(rows: list[dict], row_key: str, col_key: str, others: list[str]) -> list[tuple[dict, str]]:
    """(fixed values of the other swept keys, Markdown table of row_key x col_key) for each combination.

    A cell holds the period +- its uncertainty for PT and TU, else the regime.
    """
    out = []
    for fixed, subset in facets(rows, others):
        row_values = sorted({row[row_key] for row in subset})
        col_values = sorted({row[col_key] for row in subset})
        cells = {(row[row_key], row[col_key]): row for row in subset}
        body = []
        for r in row_values:
            line = [f"{r:g}"]
            for c in col_values:
                row = cells.get((r, c))
                if row is None:
                    line.append("")
                elif row["regime"] in ("PT", "TU") and math.isfinite(row["period"]):
                    line.append(f"{row['period']:.4g} +- {row['period_err']:.1g}" + (" (TU)" if row["regime"] == "TU"
                                                                                      else ""))
                else:
                    line.append(row["regime"])
            body.append(line)
        header = [f"{LABELS.get(row_key, row_key)} \\ {LABELS.get(col_key, col_key)}"] + [f"{c:g}" for c in col_values]
        out.append((fixed, markdown_table(header, body)))
    return out


LABELS = {"shear_rate": "S", "psi_bar": "psi_bar", "excess_length": "Delta", "B2": "B2"}


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
    else:
        ordered = sorted(varied, key=lambda k: (k != "shear_rate", varied.index(k)))
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
    return "".join(f"_{LABELS.get(k, k)}{v:g}" for k, v in fixed.items())


def facet_label(fixed: dict) -> str:
    """``B2 = 0.3``: the fixed values in a heading or a title."""
    return ", ".join(f"{LABELS.get(k, k)} = {v:g}" for k, v in fixed.items())


def regime_counts(rows: list[dict]) -> dict:
    """Number of cases per regime, in the order TT, PT, TU, undecided; regimes with none left out."""
    counts = {r: sum(1 for row in rows if row["regime"] == r) for r in REGIMES}
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

    def counts(self) -> dict:
        return regime_counts(self.rows)


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
            case_figures: bool = True, axes=None, progress=None) -> Report:
    """Classify every case of ``path``; write the tables and figures to ``out_dir`` (default:
    ``<file>_analysis`` next to it) and the results back into the file."""
    from . import plots
    from .campaign import CampaignLock

    source = read_source(path)
    settings = source.settings
    if overrides:
        settings = AnalysisSettings.from_dict({**settings.__dict__, **overrides}, where="--set")
    rows = analyse_source(source, settings, progress=None if progress is None else
                          (lambda i, n: progress(f"classified {i}/{n} cases")))
    out = Path(out_dir) if out_dir else source.path.with_name(source.path.stem + "_analysis")
    out.mkdir(parents=True, exist_ok=True)
    written = []

    write_csv(rows, out / "regimes.csv")
    (out / "regimes.md").write_text(regimes_markdown(source, rows))
    written += [out / "regimes.csv", out / "regimes.md"]

    x_key, y_key, others = grid_axes(source, rows, axes)
    searches = []
    if source.mode == "search":
        from .search_campaign import critical_markdown, critical_rows, write_critical_csv

        searches = critical_rows(source, rows)
        write_critical_csv(searches, out / "critical_shear.csv")
        (out / "critical_shear.md").write_text(critical_markdown(source.name, searches))
        written += [out / "critical_shear.csv", out / "critical_shear.md"]
        varied = [k for k in source.sweep_keys if k != "shear_rate" and len({r[k] for r in searches}) > 1]
        if varied:
            for fixed, subset in facets(searches, varied[1:]):
                fig = plots.critical_shear_figure(subset, varied[0], title=f"{source.name}" + (
                    f" ({facet_label(fixed)})" if fixed else ""))
                written += _save(fig, out / f"critical_shear{facet_suffix(fixed)}")
    if source.kind == "campaign" and len(rows) > 1 and source.mode != "search":
        tables = period_tables(rows, y_key, x_key, others)
        text = [f"# Periods of {source.name!r}\n\nPeriod of theta +- its uncertainty where the case "
                "phase-treads (PT) or tumbles (TU); otherwise its regime.\n"]
        for fixed, table in tables:
            if fixed:
                text.append(f"## {facet_label(fixed)}\n")
            text.append(table + "\n")
        (out / "periods.md").write_text("\n".join(text))
        written.append(out / "periods.md")
    if source.kind == "campaign" and len(rows) > 1:
        for fixed, subset in facets(rows, others):
            suffix = facet_suffix(fixed)
            title = f"{source.name}" + (f" ({facet_label(fixed)})" if fixed else "")
            fig = plots.phase_diagram(subset, x_key, y_key, title=title, annotate_periods=not searches)
            if searches and x_key == "shear_rate":
                plots.mark_critical(fig.axes[0], [r for r in searches if all(r[k] == v for k, v in fixed.items())],
                                    y_key)
            written += _save(fig, out / f"phase_diagram{suffix}")
            if not searches:
                written += _save(plots.period_figure(subset, y_key, x_key, title=title), out / f"periods{suffix}")
    if case_figures:
        directory = out / "cases"
        directory.mkdir(exist_ok=True)
        with open_file(source.path, "r", locking=False) as h5:
            for i, (case, row) in enumerate(zip(source.cases, rows)):
                group = h5 if source.kind == "case" else h5[f"cases/{case.case_id}"]
                store = CaseStore(group)
                title = (f"case {case.case_id}: " if source.kind == "campaign" else "") \
                    + plots.case_title(dict(group.attrs)) + f"\n{row['regime']}: {row['reason']}"
                fig = plots.case_figure(case.series, store.snapshots(), title=_wrap(title), kymographs=True)
                fig.savefig(directory / f"{case.case_id}.png", dpi=90)
                plots.plt.close(fig)
                if progress is not None:
                    progress(f"case figures {i + 1}/{len(rows)}")
        written.append(directory / f"<case>.png ({len(rows)})")

    wrote_back, note = False, ""
    if write_to_file:
        try:
            lock = CampaignLock(source.path).acquire() if source.kind == "campaign" else None
        except FileFormatError as exc:
            note = f"results not written into the file: {exc}"
        else:
            try:
                write_back(source.path, rows, settings)
                wrote_back = True
            except FileFormatError as exc:
                note = f"results not written into the file: {exc}"
            finally:
                if lock is not None:
                    lock.release()
    return Report(source, tuple(rows), tuple(written), wrote_back, note, tuple(searches))


def _save(fig, stem: Path) -> list[Path]:
    """Save a figure as PNG and PDF; close it."""
    from .plots import plt

    paths = [stem.with_name(f"{stem.name}.{ext}") for ext in ("png", "pdf")]
    for path in paths:
        fig.savefig(path, dpi=150)
    plt.close(fig)
    return paths


def _wrap(text: str, width: int = 110) -> str:
    import textwrap

    return "\n".join(textwrap.fill(line, width) for line in text.splitlines())
