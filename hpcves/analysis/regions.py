"""The regions of a phase diagram that its cases decide, for the figures (reports/diagrams.py).

A region is drawn only where the cases around it agree: between two neighbouring cases of one
row with the same regime, and between two neighbouring rows where both have it over the same
stretch. So a grid shades the rectangles whose four corner cases share a regime, a search's rows
(one a searched point) shade the stretches below and above their brackets that neighbouring rows
share, and nothing is drawn beyond the outermost cases or across a boundary: the boundaries lie
in the white left between the regions, where no case says which side a point is on. A refinement
has its own cells (refine.regions), which the same rule applied to a regular grid would give.
"""
from __future__ import annotations

from hpcves.analysis.refine import decided


def row_intervals(row: list[tuple[float, str]]) -> list[tuple[float, float, str]]:
    """(start, end, outcome) of every stretch of a row of cases, (position, outcome), whose
    neighbouring cases share one decided outcome (a stretch of one case has no length: left out)."""
    out = []
    row = sorted(row)
    start = 0
    for k in range(1, len(row) + 1):
        if k == len(row) or row[k][1] != row[start][1]:
            if k - 1 > start and decided(row[start][1]):
                out.append((row[start][0], row[k - 1][0], row[start][1]))
            start = k
    return out


def row_regions(outcomes: dict, rows_along_x: bool = True) -> list[tuple[tuple, str]]:
    """((x0, x1, y0, y1), outcome) of every rectangle between two neighbouring rows of cases that
    both rows decide alike; ``outcomes`` = {(x, y): outcome}; ``rows_along_x``: rows of constant y
    (a search along x), else of constant x."""
    rows: dict[float, list] = {}
    for (x, y), outcome in outcomes.items():
        along, across = (x, y) if rows_along_x else (y, x)
        rows.setdefault(across, []).append((along, outcome))
    levels = sorted(rows)
    out = []
    for lower, upper in zip(levels, levels[1:]):
        for a0, a1, outcome in row_intervals(rows[lower]):
            for b0, b1, other in row_intervals(rows[upper]):
                start, end = max(a0, b0), min(a1, b1)
                if other == outcome and end > start:
                    box = (start, end, lower, upper) if rows_along_x else (lower, upper, start, end)
                    out.append((box, outcome))
    return sorted(out)
