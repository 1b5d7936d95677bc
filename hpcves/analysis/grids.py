"""Which grids a run with N adapting (numerics.N = "auto") spent its work on, from its samples.

The samples record ``t``, ``N`` (the grid the run goes on with after the sample) and ``step``
(the steps taken up to it). The interval from sample k to sample k + 1 ran on N_k: its
steps, step_{k+1} - step_k, and its time, t_{k+1} - t_k, count for N_k (after a tension solve
that gave out inside the interval, its last steps ran one size up: counted on N_k all the same).
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np


def grid_use(t: np.ndarray, N: np.ndarray, step: np.ndarray | None = None) -> dict[int, tuple[float, float]]:
    """{N: (simulated time, steps)} of one run's samples; steps NaN where ``step`` is not recorded."""
    t, N = np.asarray(t, float), np.asarray(N, float)
    keep = np.isfinite(t) & np.isfinite(N)
    t, N = t[keep], N[keep]
    steps = np.full(t.size, np.nan) if step is None else np.asarray(step, float)[keep]
    if t.size < 2:
        return {}
    use: dict[int, tuple[float, float]] = {}
    for n, dt, ds in zip(N[:-1].astype(int), np.diff(t), np.diff(steps)):
        time, taken = use.get(int(n), (0.0, 0.0))
        use[int(n)] = (time + float(dt), taken + float(ds))
    return dict(sorted(use.items()))


def combined(uses: Iterable[Mapping[int, tuple[float, float]]]) -> dict[int, tuple[float, float]]:
    """The sum of several runs' :func:`grid_use` (steps NaN if any run lacks them)."""
    total: dict[int, tuple[float, float]] = {}
    for use in uses:
        for n, (time, taken) in use.items():
            t0, s0 = total.get(n, (0.0, 0.0))
            total[n] = (t0 + time, s0 + taken)
    return dict(sorted(total.items()))


def shares(use: Mapping[int, tuple[float, float]]) -> dict[int, tuple[float, float]]:
    """{N: (share of the time, share of the steps)}, each summing to 1 (NaN where unknown)."""
    time = sum(v[0] for v in use.values())
    steps = sum(v[1] for v in use.values())
    return {n: (v[0] / time if time > 0 else np.nan, v[1] / steps if steps > 0 else np.nan)
            for n, v in use.items()}


def use_text(use: Mapping[int, tuple[float, float]]) -> str:
    """'64: 12 % of the steps (30 % of the time), 96: ...' -- or by time alone where steps are unknown."""
    parts = []
    for n, (time, steps) in shares(use).items():
        if np.isfinite(steps):
            parts.append(f"{n}: {100 * steps:.0f} % of the steps ({100 * time:.0f} % of the time)")
        else:
            parts.append(f"{n}: {100 * time:.0f} % of the simulated time")
    return ", ".join(parts)
