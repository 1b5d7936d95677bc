"""Tables for people and for programs: Markdown tables and CSV files of rows."""
from __future__ import annotations

import csv
import math
from pathlib import Path


def markdown_table(header: list[str], body: list[list[str]], left: tuple = (0,)) -> str:
    """A Markdown table; the columns numbered in ``left`` are left-aligned, the others right-aligned."""
    lines = ["| " + " | ".join(header) + " |",
             "| " + " | ".join("---" if i in left else "---:" for i in range(len(header))) + " |"]
    lines += ["| " + " | ".join(cell.replace("|", "/") for cell in row) + " |" for row in body]
    return "\n".join(lines)


def write_rows(rows: list[dict], columns: tuple, path: Path) -> None:
    """A CSV file of ``rows`` with these ``columns`` (floats to 6 digits, nan as an empty cell)."""
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(columns)
        for row in rows:
            writer.writerow([cell(row[c]) for c in columns])


def cell(value) -> str:
    """A table cell: a number to 6 significant digits, NaN or None as an empty cell, text as it is."""
    if value is None:
        return ""
    if isinstance(value, str):
        return value
    return f"{value:.6g}" if math.isfinite(value) else ""


def fmt(value, spec: str) -> str:
    """A float in format ``spec``; NaN (or anything not a float) as an empty cell."""
    return format(value, spec) if isinstance(value, float) and math.isfinite(value) else ""
