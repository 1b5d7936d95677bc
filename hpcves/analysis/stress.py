"""The settled mean and amplitude of a rheology series ([eta], N1: model/rheology.py); pure functions.

A series is read over the part of the run the classification found settled (regimes.classify: from
t_settle on, theta's period), as theta's mean is (periodicity.analyze, item 7):

* periodic (PT, TU): the mean over the last m whole periods of theta -- a whole number of the series'
  periods too, so no bias from a fraction of one -- with theta's mean's error
  (periodicity.whole_period_mean: the window's ends, the period's error, the noise, the drift);
* steady (TT): the mean over the settled part, uncertain by max(|drift|, 5 sigma) (the part from
  t_settle on changes by the drift; 5 sigma: the band periodicity.analyze calls steady).

The amplitude is half the range over the settled part.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hpcves.analysis.periodicity import noise_level, period_trend, whole_period_mean


@dataclass(frozen=True)
class SettledMean:
    mean: float
    amplitude: float
    error: float          # statistical uncertainty of ``mean``

    @classmethod
    def none(cls) -> "SettledMean":
        return cls(math.nan, math.nan, math.nan)


def settled_mean(t, x, t_settle: float, period: float = math.nan, period_error: float = math.nan) -> SettledMean:
    """Mean, amplitude and the mean's statistical error of x(t) (uniform samples) from ``t_settle`` on,
    over the last whole ``period``s where one is given (module docstring); none where fewer than 8
    finite samples are settled."""
    t, x = np.asarray(t, dtype=float), np.asarray(x, dtype=float)
    keep = np.isfinite(t) & np.isfinite(x) & ((t >= t_settle) if math.isfinite(t_settle) else True)
    t, x = t[keep], x[keep]
    if x.size < 8:
        return SettledMean.none()
    h = (t[-1] - t[0]) / (x.size - 1)
    noise = noise_level(x)
    amplitude = float(0.5 * (x.max() - x.min()))
    lag = int(round(period / h)) if math.isfinite(period) and period > 0 else 1
    drift = period_trend(x, lag) * (x.size - 1)
    over_periods = whole_period_mean(t, x, float(t[0]), h, period, period_error, amplitude, noise, drift)
    if over_periods is None:
        return SettledMean(float(x.mean()), amplitude, float(max(abs(drift), 5.0 * noise)))
    return SettledMean(over_periods[0], amplitude, over_periods[1])
