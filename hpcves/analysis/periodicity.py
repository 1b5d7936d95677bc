"""Steady or periodic? The end of the transient, the period and its uncertainty (pure numpy).

The method (docs/analysis.md has the reasoning and the numbers behind the defaults):

1. **Noise** sigma: the median absolute fourth difference, scaled
   (sigma = MAD(d4 x) / 0.6745 / sqrt 70); a smooth signal sampled finely has
   almost none, white noise of standard deviation s gives s.
2. **Steady or oscillating**: the last quarter of the record is steady if its
   range is within the tolerance ``tol = max(abs_tol, 5 sigma)``.
3. **End of the transient** ``t_settle``: for a steady signal, the first time
   after which x stays within ``tol`` of its final value. For an oscillating
   one, windows of one (provisional) period are slid along the record, with
   the linear trend of the second half removed; the transient ends with the
   first window after which every window's max and min stay within
   ``max(tol, rel_tol x range)`` of those of the last quarter.
4. **Drift removed** from the settled part: the slope of its one-period moving
   average and its mean over the last whole periods (a straight line fitted to
   the samples tilts with the phase at which the record ends, and moved the
   crossings of sin 2 pi t / T by 0.14 % of T over 8.45 cycles).
5. **Autocorrelation** (unbiased): its first peak at least 80 % as high as
   the highest, refined by a parabola through the three samples around it and
   then at every multiple m T within half the record; T_acf is the
   least-squares slope of the peak lags against m. It finds the period's scale
   robustly but is biased by the finite record (0.16 % at 8.45 cycles).
6. **Mid-line crossings**: upward crossings of the settled signal's mid-line
   with a hysteresis of a quarter of its half-range (noise cannot add
   crossings; a noisy signal is first averaged over 1/8 period), located by
   linear interpolation, T_cross the slope of crossing time against index. A
   waveform may cross more than once per period, so T_acf is compared with
   m T_cross for the nearest integer m, and the estimates ``agree`` when they
   differ by at most 1 %. With at least MIN_CROSSINGS = 5 crossings and
   agreement the **period is m T_cross** (unbiased: 1e-8 relative on the same
   8.45 cycles), uncertain by m sigma_cross, the standard error of the slope
   (with a round-off floor); otherwise T_acf, uncertain by
   ``max(sigma_acf, m sigma_cross, |T_acf - m T_cross|)``.
7. **Mean** of an oscillating signal over the last m whole periods of the
   settled part (a fraction of a period would bias it by up to A / cycles),
   uncertain by ``mean_error = max(|drift|, 2 A (h + m period_err) / (m T)
   + 2 sigma / sqrt(k))`` (the window's ends fall between samples h apart and
   move with the period's error; k samples of noise sigma); of a steady one
   over the settled part, uncertain by ``tol``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import lstsq
from scipy.ndimage import maximum_filter1d, minimum_filter1d

#: an autocorrelation peak counts as the period if it is this high relative to the highest one
PEAK_FRACTION = 0.8
#: hysteresis of the crossing check, relative to the half-range of the signal
HYSTERESIS = 0.25
#: the two period estimates agree when they differ by at most this fraction
AGREEMENT = 0.01
#: crossings (3 degrees of freedom in their fit) from which their period is the estimate
MIN_CROSSINGS = 5


@dataclass(frozen=True)
class PeriodEstimate:
    """A period from the autocorrelation, checked against mid-line crossings (nan: none found)."""

    period: float
    error: float
    acf_period: float
    acf_error: float
    acf_peak: float            # autocorrelation at the period: 1 for a perfectly periodic signal
    crossing_period: float     # period of the crossings times crossings_per_period (nan if < 3 crossings)
    crossing_error: float
    crossings_per_period: int
    agree: bool | None         # None: too few crossings to check

    @staticmethod
    def none() -> "PeriodEstimate":
        nan = float("nan")
        return PeriodEstimate(nan, nan, nan, nan, nan, nan, nan, 0, None)


@dataclass(frozen=True)
class SignalAnalysis:
    """What :func:`analyze` finds in x(t); amplitudes and extremes are over the settled part."""

    t_settle: float            # end of the transient (nan: never settles)
    settled_span: float        # t_end - t_settle
    steady: bool               # the last quarter stays within tol
    tolerance: float           # the absolute tolerance used (max(abs_tol, 5 noise))
    noise: float
    mean: float
    minimum: float
    maximum: float
    amplitude: float           # (max - min) / 2
    drift: float               # change of the linear trend over the settled part
    period: PeriodEstimate
    mean_error: float = float("nan")   # statistical uncertainty of ``mean`` (see :func:`analyze`)

    @property
    def cycles(self) -> float:
        """Settled periods in the record."""
        p = self.period.period
        return self.settled_span / p if np.isfinite(p) and p > 0 else 0.0


# ---------------------------------------------------------------------- building blocks
def noise_level(x: np.ndarray) -> float:
    """Standard deviation of white noise on a smooth signal: MAD(fourth differences) / 0.6745 / sqrt 70.

    A fourth difference of white noise has variance C(8,4) sigma^2 = 70 sigma^2;
    that of a smooth signal sampled k times per period is (2 pi / k)^4 times
    its amplitude (1e-5 at 140 samples per period), so it is not mistaken for noise.
    """
    if x.size < 9:
        return 0.0
    d4 = np.diff(x, 4)
    return float(np.median(np.abs(d4 - np.median(d4))) / 0.6745 / np.sqrt(70.0))


def detrend(x: np.ndarray) -> np.ndarray:
    """x minus its least-squares straight line, fitted over A = [(i + 1) / n, 1] by LAPACK's gelsd:
    the arithmetic of ``scipy.signal.detrend(x, type="linear")`` step for step (bitwise its result:
    tests/test_periodicity.py), without importing scipy.signal, which costs ~0.3-0.5 s a process
    (every rank that classifies, every run that decides)."""
    data = np.array(x, dtype=float).reshape(-1, 1)
    n = data.shape[0]
    A = np.ones((n, 2))
    A[:, 0] = np.arange(1, n + 1, dtype=float) / n
    coef = lstsq(A, data)[0]
    return (data - A @ coef).reshape(-1)


def local_maxima(x: np.ndarray) -> np.ndarray:
    """Indices of the local maxima of x, a plateau by its middle ((first + last) // 2), never the ends:
    what ``scipy.signal.find_peaks(x)[0]`` returns with no conditions (tests/test_periodicity.py),
    without importing scipy.signal. A run of equal values is a maximum when the runs on both sides
    are lower."""
    x = np.asarray(x, dtype=float)
    if x.size < 3:
        return np.zeros(0, dtype=np.intp)
    starts = np.concatenate(([0], np.flatnonzero(x[1:] != x[:-1]) + 1))
    lasts = np.concatenate((starts[1:] - 1, [x.size - 1]))
    values = x[starts]
    inner = np.arange(1, starts.size - 1)
    top = inner[(values[inner - 1] < values[inner]) & (values[inner + 1] < values[inner])]
    return ((starts[top] + lasts[top]) // 2).astype(np.intp)


def untilted(x: np.ndarray, lag: float) -> np.ndarray:
    """x minus its drift and its mean, both taken over whole periods of ``lag`` samples.

    A straight line fitted to an oscillation tilts with the phase at which the record ends (by
    up to amplitude / cycles), and crossings of a tilted mid-line drift by a fraction of a
    sample per period: 0.14 % off the period of sin 2 pi t / T over 8.45 cycles. The drift of
    the one-period moving average (:func:`period_trend`) and the mean over the last whole
    periods do not tilt."""
    i = np.arange(x.size, dtype=float)
    z = x - period_trend(x, int(round(lag))) * i
    whole = int(x.size // lag) if lag > 0 else 0
    tail = z[-int(round(whole * lag)):] if whole >= 1 else z
    return z - tail.mean()


def period_trend(x: np.ndarray, window: int) -> float:
    """Slope (per sample) of the one-period moving average of x: the drift of an oscillating
    signal. A straight line fitted to x itself would tilt with the phase at which the record
    ends (by up to amplitude / cycles); averaging over whole periods first does not."""
    window = max(int(window), 1)
    if x.size < window + 2:
        return float(np.polyfit(np.arange(x.size, dtype=float), x, 1)[0]) if x.size >= 2 else 0.0
    c = np.cumsum(np.r_[0.0, x])
    mean = (c[window:] - c[:-window]) / window
    return float(np.polyfit(np.arange(mean.size, dtype=float), mean, 1)[0])


def autocorrelation(x: np.ndarray) -> np.ndarray:
    """Unbiased, normalised autocorrelation r(k) = <y_i y_(i+k)> / <y_i^2>, y = x - mean (via FFT)."""
    n = x.size
    y = x - x.mean()
    f = np.fft.rfft(y, 2 * n)
    r = np.fft.irfft(f * np.conj(f), 2 * n)[:n]
    r = r / np.arange(n, 0, -1)
    return r / r[0] if r[0] > 0 else np.zeros(n)


def _parabolic_peak(r: np.ndarray, k: int) -> float:
    """Lag of the maximum of the parabola through r[k-1], r[k], r[k+1]."""
    a, b, c = r[k - 1], r[k], r[k + 1]
    curvature = a - 2 * b + c
    return k + (0.5 * (a - c) / curvature if curvature < 0 else 0.0)


def acf_period(x: np.ndarray) -> tuple[float, float, float]:
    """(period, standard error, peak height) in samples from the autocorrelation; nans if none.

    Needs two periods in the record: lags beyond half the record are not used.
    """
    n = x.size
    nan = float("nan")
    if n < 8:
        return nan, nan, nan
    r = autocorrelation(x)
    k_max = n // 2
    negative = np.nonzero(r[1:k_max] < 0)[0]
    if negative.size == 0:
        return nan, nan, nan              # never decorrelates: no oscillation within half the record
    lo = negative[0] + 1
    # local maxima at lags lo .. k_max - 2 (never the ends of the segment, which holds their
    # neighbours), above zero
    peaks = local_maxima(r[lo - 1:k_max]) + lo - 1
    peaks = peaks[r[peaks] > 0]
    if peaks.size == 0:
        return nan, nan, nan
    heights = r[peaks]
    first = peaks[np.nonzero(heights >= PEAK_FRACTION * heights.max())[0][0]]
    t1 = _parabolic_peak(r, first)
    lags, orders = [t1], [1]
    m = 2
    while m * t1 + t1 / 4 < k_max - 1:
        centre = m * t1
        window = np.arange(max(int(centre - t1 / 4), 1), min(int(centre + t1 / 4) + 1, k_max - 1))
        best = window[np.argmax(r[window])]
        if 0 < best < k_max - 1 and r[best] >= r[best - 1] and r[best] > r[best + 1]:
            lags.append(_parabolic_peak(r, best))
            orders.append(m)
        m += 1
    lags, orders = np.array(lags), np.array(orders, dtype=float)
    period = float(np.sum(orders * lags) / np.sum(orders ** 2))
    if lags.size >= 3:
        residual = lags - orders * period
        error = float(np.sqrt(np.sum(residual ** 2) / (lags.size - 1) / np.sum(orders ** 2)))
    else:
        error = nan                       # judged by the crossing check alone
    return period, error, float(r[first])


def upward_crossings(t: np.ndarray, y: np.ndarray, hysteresis: float) -> np.ndarray:
    """Times at which y crosses 0 upwards, counting a crossing only once y has been below
    -hysteresis before and gets above +hysteresis after (linear interpolation between samples)."""
    side = np.where(y > hysteresis, 1, np.where(y < -hysteresis, -1, 0))
    where = np.nonzero(side)[0]
    if where.size < 2:
        return np.empty(0)
    s = side[where]
    rise = np.nonzero((s[:-1] == -1) & (s[1:] == 1))[0]
    ends = where[rise + 1]                        # first sample above +hysteresis
    zero_up = np.nonzero((y[:-1] < 0) & (y[1:] >= 0))[0]
    last = zero_up[np.searchsorted(zero_up, ends) - 1]   # last zero up-crossing before it
    return t[last] - y[last] * (t[last + 1] - t[last]) / (y[last + 1] - y[last])


def crossing_fit(times: np.ndarray) -> tuple[float, float]:
    """Slope of crossing time against crossing index and its standard error (nans if < 3)."""
    if times.size < 3:
        return float("nan"), float("nan")
    j = np.arange(times.size, dtype=float)
    (slope, intercept), residual = np.polyfit(j, times, 1, full=True)[:2]
    dof = times.size - 2
    s2 = float(residual[0]) / dof if dof > 0 and residual.size else 0.0
    return float(slope), float(np.sqrt(s2 / np.sum((j - j.mean()) ** 2)))


def estimate_period(t: np.ndarray, x: np.ndarray) -> PeriodEstimate:
    """The period of x(t), uniformly sampled, after removing its drift (steps 4-6 above)."""
    if x.size < 8:
        return PeriodEstimate.none()
    h = float((t[-1] - t[0]) / (t.size - 1))
    lag = acf_period(detrend(x))[0]
    if not np.isfinite(lag):
        return PeriodEstimate.none()
    y = untilted(x, lag)
    lag, lag_error, peak = acf_period(y)
    if not np.isfinite(lag):
        return PeriodEstimate.none()
    T_acf, s_acf = lag * h, lag_error * h
    width = max(int(round(lag / 8)), 1)
    if width > 1 and noise_level(y) > 1e-3 * 0.5 * (y.max() - y.min()):
        # noisy: cross a moving average over 1/8 period (symmetric, so it shifts no crossing)
        y = np.convolve(y, np.full(width, 1.0 / width), mode="valid")
        t = t[(width - 1) // 2:][: y.size]
    mid = 0.5 * (y.max() + y.min())
    crossings = upward_crossings(t, y - mid, HYSTERESIS * 0.5 * (y.max() - y.min()))
    T_c, s_c = crossing_fit(crossings)
    if not np.isfinite(T_c) or T_c <= 0:
        return PeriodEstimate(T_acf, s_acf, T_acf, s_acf, peak,
                              float("nan"), float("nan"), 0, None)
    m = max(1, int(round(T_acf / T_c)))
    difference = abs(T_acf - m * T_c)
    agree = difference <= AGREEMENT * T_acf
    if not agree or crossings.size < MIN_CROSSINGS:
        return PeriodEstimate(T_acf, float(np.nanmax([s_acf, m * s_c, difference])), T_acf, s_acf, peak,
                              m * T_c, m * s_c, m, agree)
    roundoff = 16 * np.finfo(float).eps * float(np.abs(t).max())       # crossing times carry it
    return PeriodEstimate(m * T_c, max(m * s_c, roundoff), T_acf, s_acf, peak, m * T_c, m * s_c, m, agree)


def settle_index(within: np.ndarray) -> int:
    """First index from which ``within`` holds for every later element (len(within) if never)."""
    bad = np.nonzero(~within)[0]
    return int(bad[-1] + 1) if bad.size else 0


# ---------------------------------------------------------------------- the whole signal
def analyze(t: np.ndarray, x: np.ndarray, *, abs_tol: float = 1e-4, rel_tol: float = 0.05) -> SignalAnalysis:
    """Transient, steadiness and period of x(t), sampled uniformly (module docstring)."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    finite = np.isfinite(x) & np.isfinite(t)
    t, x = t[finite], x[finite]
    n = x.size
    nan = float("nan")
    if n < 8:
        return SignalAnalysis(nan, 0.0, False, abs_tol, nan, nan, nan, nan, nan, nan, PeriodEstimate.none())
    noise = noise_level(x)
    tol = max(abs_tol, 5.0 * noise)
    tail = x[-max(n // 4, 2):]
    steady = float(tail.max() - tail.min()) <= 2 * tol
    if steady:
        final = float(np.median(tail))
        start = settle_index(np.abs(x - final) <= tol)
        period = PeriodEstimate.none()
    else:
        half = n // 2
        lag = acf_period(detrend(x[half:]))[0]
        if not np.isfinite(lag):                           # a long period: try the whole record
            lag = acf_period(detrend(x))[0]
        if not np.isfinite(lag):                           # oscillates, but no period to go by
            return SignalAnalysis(nan, 0.0, False, tol, noise, float(x.mean()), float(x.min()),
                                  float(x.max()), float(0.5 * (x.max() - x.min())), nan, PeriodEstimate.none())
        window = min(int(round(lag)) + 1, n // 4)
        z = x - period_trend(x[half:], window - 1) * np.arange(n)   # the second half's drift removed
        origin = -(window // 2)                            # window [i, i + window)
        upper = maximum_filter1d(z, window, origin=origin)[: n - window + 1]
        lower = minimum_filter1d(z, window, origin=origin)[: n - window + 1]
        ztail = z[-max(n // 4, window):]
        hi, lo = ztail.max(), ztail.min()
        band = max(tol, rel_tol * (hi - lo))
        start = settle_index((np.abs(upper - hi) <= band) & (np.abs(lower - lo) <= band))
        period = estimate_period(t[start:], x[start:]) if start < n - 8 else PeriodEstimate.none()
    if start >= n:
        return SignalAnalysis(nan, 0.0, steady, tol, noise, nan, nan, nan, nan, nan, period)
    settled = x[start:]
    h = (t[-1] - t[0]) / (n - 1)
    lag = period.period / h if np.isfinite(period.period) else 1
    drift = period_trend(settled, int(round(lag))) * (settled.size - 1)
    amplitude = float(0.5 * (settled.max() - settled.min()))
    mean, mean_error = float(settled.mean()), (tol if steady else float("nan"))
    over_periods = whole_period_mean(t, x, float(t[start]), h, period.period, period.error, amplitude, noise, drift)
    if over_periods is not None:
        mean, mean_error = over_periods
    return SignalAnalysis(float(t[start]), float(t[-1] - t[start]), steady, tol, noise, mean,
                          float(settled.min()), float(settled.max()), amplitude, drift, period, mean_error)


def whole_period_mean(t: np.ndarray, x: np.ndarray, t_start: float, h: float, period: float, period_error: float,
                      amplitude: float, noise: float, drift: float) -> tuple[float, float] | None:
    """(mean, its error) of x(t), uniform samples h apart, over the last whole periods after t_start
    (item 7 of the module docstring); None where no whole period fits. No bias from a fraction of a
    period; what is left: the samples at the window's ends (h), the period's own error (m dT), the
    noise, and the drift."""
    if not (np.isfinite(period) and period > 0):
        return None
    whole = int((t[-1] - t_start) // period)
    if whole < 1:
        return None
    span = whole * period
    window = x[t >= t[-1] - span - 1e-9 * h]
    ends = 2.0 * amplitude * (h + whole * (period_error if np.isfinite(period_error) else 0.0)) / span
    return float(np.mean(window)), float(max(abs(drift), ends + 2.0 * noise / np.sqrt(window.size)))


@dataclass(frozen=True)
class Period:
    period: float          # mean interval between upward mid-line crossings (nan if < 2)
    spread: float          # standard deviation of those intervals
    cycles: int            # number of complete intervals used
    amplitude: float       # (max - min) / 2 over the window
    start: float = np.nan  # first and last upward crossing: [start, end] holds whole cycles
    end: float = np.nan


def crossing_period(t: np.ndarray, x: np.ndarray, t_start: float | None = None) -> Period:
    """Period of x(t) from plain upward crossings of its mid-line (max + min)/2 after ``t_start``.

    The quick check used by the solver's validation and benchmark: no
    hysteresis, no trend removal (:func:`estimate_period` has both).

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
