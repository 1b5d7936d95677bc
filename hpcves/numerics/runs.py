"""Runs of a condition around a closed (periodic) sequence of points."""
from __future__ import annotations

import numpy as np


def periodic_runs(mask) -> list[tuple[int, int]]:
    """The maximal runs of True in ``mask`` read periodically, as (first index, length) pairs in index
    order; a run through index 0 starts before it (its first index is the one after the last False).
    All True: one run [(0, n)]; all False: none."""
    mask = np.asarray(mask, dtype=bool)
    n = mask.size
    if mask.all():
        return [(0, n)]
    if not mask.any():
        return []
    start = int(np.argmin(mask))                       # a False point: no run wraps past it
    edges = np.diff(np.r_[0, np.roll(mask, -start).astype(np.int8), 0])
    firsts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return sorted(((int(f) + start) % n, int(e - f)) for f, e in zip(firsts, ends))
