"""Analysis of time series (pure functions).

So far: the period of an oscillating signal from its mid-line crossings. The
full classification (transient detection, uncertainty from autocorrelation,
regimes) is the subject of ``hpcves analyze``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Period:
    period: float          # mean interval between upward mid-line crossings (nan if < 2)
    spread: float          # standard deviation of those intervals
    cycles: int            # number of complete intervals used
    amplitude: float       # (max - min) / 2 over the window
    start: float = np.nan  # first and last upward crossing: [start, end] holds whole cycles
    end: float = np.nan


def crossing_period(t: np.ndarray, x: np.ndarray, t_start: float | None = None) -> Period:
    """Period of x(t) from upward crossings of its mid-line (max + min)/2 after ``t_start``.

    Crossing times are located by linear interpolation between samples. The
    mid-line, not the mean, is used so that peaked waveforms (long dwell, short
    excursion) cross it exactly twice per cycle.
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    if t_start is not None:
        keep = t >= t_start
        t, x = t[keep], x[keep]
    if x.size < 3:
        return Period(np.nan, np.nan, 0, np.nan)
    mid = 0.5 * (x.max() + x.min())
    amplitude = 0.5 * (x.max() - x.min())
    y = x - mid
    up = np.nonzero((y[:-1] < 0) & (y[1:] >= 0))[0]
    crossings = t[up] - y[up] * (t[up + 1] - t[up]) / (y[up + 1] - y[up])
    intervals = np.diff(crossings)
    if intervals.size == 0:
        return Period(np.nan, np.nan, 0, amplitude)
    return Period(float(intervals.mean()), float(intervals.std()), int(intervals.size), float(amplitude),
                  float(crossings[0]), float(crossings[-1]))
