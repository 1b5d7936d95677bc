"""Tank-treading, phase-treading, tumbling -- or undecided (SPEC section 4); pure functions.

A case is classified from its time series: the inclination theta(t) and the
velocity of the phase pattern in the lab frame, V_psi + V_L, against the
membrane's tank-treading velocity V (all recorded by diagnostics.py).

* **TT**: after the transient theta is steady and the pattern is fixed in the
  lab frame: |<V_psi + V_L>| <= pattern_tol |<V>| (for psi = 0, or a mixture
  that never separates -- psi_max - psi_min < MIXED = 0.5 over the settled
  part, as for psi_bar = 0.1, outside the spinodal -- there is no pattern and
  theta alone decides; so too where the pattern has no position: the
  psi-weighted circular mean of alpha vanishes for a pattern with two-fold
  symmetry, as the soft phase gathered at both tips of a deflated vesicle, and
  V_psi is then undefined or noise -- NaN in over UNDEFINED of the settled
  samples, or a spread over NOISY times the tank-treading speed).
* **PT**: the pattern moves in the lab frame and theta oscillates with a
  period (checked two ways, periodicity.py), at least ``min_cycles`` settled
  periods long, with min theta >= 0.
* **TU**: the same, but min theta < 0 over the settled signal -- the publication's criterion. The
  vesicle flips (theta passes through +-pi/2; its period from sin 2 theta, which stays continuous
  where theta is folded), or it only swings below 0 and back without flipping (``flips`` = 0, and
  the reason says so: swinging, not tumbling). A flipping theta whose sampled extremes jitter too
  much to settle is settled by its flips (:func:`settled_by_flips`).
* **undecided** otherwise -- too short, not settled, still drifting, no
  consistent period, or theta and the pattern disagree -- with the reason.

Two outcomes come from how the run ended, not from the series: **model limit**
(psi left the range where the linear bending law holds: runner.beyond_model)
and **failed** (the numerics gave out or the code raised).

Every classification carries its evidence (settling time, period and its
uncertainty, theta's mean, minimum and amplitude, the pattern's speed).
"""
from __future__ import annotations

import re
from dataclasses import asdict, dataclass, fields, replace

import numpy as np

from hpcves.analysis.periodicity import PeriodEstimate, SignalAnalysis, analyze, estimate_period
from hpcves.config import check_type, from_table
from hpcves.model.params import ConfigError

TT, PT, TU, UNDECIDED = "TT", "PT", "TU", "undecided"
REGIMES = (TT, PT, TU, UNDECIDED)
#: the regime column of a case whose run ended at the model's limit or failed (analysis.analyze_case)
MODEL_LIMIT, FAILED = "model limit", "failed"
OUTCOMES = (*REGIMES, MODEL_LIMIT, FAILED)

#: psi_max - psi_min below which psi is a mixture, not a pattern of domains. Separated
#: domains span ~[0, 1]; a mixture outside the spinodal (psi_bar = 0.1) decays to a
#: contrast of ~0.03, and the velocity of its vanishing first mode is meaningless.
#: A constant, not an [analysis] setting: search files fingerprint those settings.
MIXED = 0.5
#: the pattern's velocity means nothing when it is NaN (no first circular moment) in more than this
#: share of the settled samples ...
UNDEFINED = 0.1
#: ... or when its spread exceeds this many tank-treading speeds (a moment of round-off size: Delta = 2.3,
#: psi_bar = 0.48, S = 28 had a spread of 31 of them, theta steady to 1e-6 and E_b to 2e-5)
NOISY = 3.0
#: what a TU case that never flips is (the classification's reason says it)
SWINGING = ("swinging: the inclination oscillates about a positive mean and dips below 0, the vesicle "
            "never turning over; Noguchi & Gompper, PRL 98, 128103 (2007); tumbling by the criterion min theta < 0")
#: the reason of an undecided case whose theta is steady while its pattern moves: where it is not
#: physics, the creep of a tank-treading pattern on too coarse a grid (docs/numerics.md), which a
#: refinement runs again with a tighter numerics.resize_tail (``[refine] min_resize_tail``)
CREEPING = re.compile(r"theta steady at -?[0-9.]+ but the pattern moves")
#: the reason of an undecided case whose theta neither settled nor repeated, or whose periodic mean still
#: drifted, to the end of its run: where it is not physics, a motion the step's tolerance does not resolve --
#: at Delta = 2.3, psi_bar = 0.48, S = 40 rtol = 1e-3 wandered for 800 shear times where rtol = 1e-4
#: phase-treads (docs/numerics.md) -- which a refinement runs again with a tighter numerics.rtol
#: (``[refine] min_rtol``)
UNSETTLED = re.compile(r"not settled: theta still changes|theta still drifting")


@dataclass(frozen=True)
class AnalysisSettings:
    """Thresholds of the classification (``[analysis]`` in a campaign file, or ``--set``)."""

    abs_tol: float = 1e-4            # rad: theta within this is steady; floor of every band
    rel_tol: float = 0.05            # settling band, relative to the settled range of theta
    min_cycles: float = 3.0          # settled periods needed to call a motion periodic
    min_settled_fraction: float = 0.2  # a steady signal must be settled over this part of the record
    pattern_tol: float = 1e-3        # |<V_psi + V_L>| / |<V>| above which the pattern moves
    min_samples: int = 50

    def __post_init__(self):
        for f in fields(self):
            value = check_type(f"analysis.{f.name}", getattr(self, f.name), int if f.type == "int" else float)
            object.__setattr__(self, f.name, value)
            if not value > 0:
                raise ConfigError(f"analysis.{f.name} = {value!r}: must be > 0")
        if self.min_settled_fraction >= 1 or self.rel_tol >= 1:
            raise ConfigError("analysis.min_settled_fraction and analysis.rel_tol must be < 1")

    @classmethod
    def from_dict(cls, values: dict, where: str = "[analysis]") -> "AnalysisSettings":
        return from_table(cls, values, where, "analysis")


@dataclass(frozen=True)
class Classification:
    regime: str
    reason: str                # the evidence in words
    t_settle: float
    period: float
    period_err: float
    cycles: float
    theta_mean: float
    theta_mean_err: float      # its statistical uncertainty (periodicity.analyze: mean_error)
    theta_min: float
    theta_amplitude: float
    theta_drift: float
    pattern_speed: float       # |<V_psi + V_L>| / |<V>| over the settled part (nan: no pattern)
    period_crossings: float    # the crossing check of the period (nan: not available)
    bending_gap: float = float("nan")       # Delta E_b = max - min of E_b over a period (PT; bending_gap())
    bending_gap_err: float = float("nan")
    flips: float = float("nan")             # TU: flips through +-pi/2 in the settled part (0: it swings)

    def row(self) -> dict:
        return asdict(self)


def bending_gap(t: np.ndarray, energy: np.ndarray, period: float, t_settle: float) -> tuple[float, float]:
    """Delta E_b = max - min of the bending energy over one period (the publication relates it to S_C),
    averaged over the last whole periods of the settled part, and its uncertainty.

    The uncertainty: the standard error of the per-period values (their scatter over k periods,
    std / sqrt k; with one period, its whole size), plus what sampling every h can miss of a smooth
    extremum, gap (1 - cos(pi h / T)) for the maximum and minimum together. The time step's error of
    E_b is not estimated. (nan, nan) without a period or a whole settled period.
    """
    t, energy = np.asarray(t, dtype=float), np.asarray(energy, dtype=float)
    if not (np.isfinite(period) and period > 0 and np.isfinite(t_settle)) or t.size < 2:
        return float("nan"), float("nan")
    whole = int((t[-1] - t_settle) // period)
    if whole < 1:
        return float("nan"), float("nan")
    h = float((t[-1] - t[0]) / (t.size - 1))
    gaps = []
    for j in range(whole):
        window = (t > t[-1] - (j + 1) * period - 1e-9 * h) & (t <= t[-1] - j * period + 1e-9 * h)
        values = energy[window]
        if values.size:
            gaps.append(float(values.max() - values.min()))
    gaps = np.array(gaps)
    gap = float(gaps.mean())
    scatter = float(gaps.std(ddof=1) / np.sqrt(gaps.size)) if gaps.size > 1 else gap
    return gap, scatter + gap * (1.0 - np.cos(np.pi * h / period))


def _settled_mean(t, values, t_settle) -> float:
    if values is None:
        return float("nan")
    keep = (t >= t_settle) & np.isfinite(values)
    return float(np.mean(values[keep])) if keep.any() else float("nan")


def classify(series: dict, settings: AnalysisSettings = AnalysisSettings()) -> Classification:
    """The regime of one case from its time series (``t``, ``theta``; ``V_psi``, ``V_L`` and
    ``tank_treading_velocity`` where recorded)."""
    t = np.asarray(series["t"], dtype=float)
    theta = np.asarray(series["theta"], dtype=float)
    a = analyze(t, theta, abs_tol=settings.abs_tol, rel_tol=settings.rel_tol)
    # a flipping theta that does not settle on its own: judged by its flips (settled_by_flips)
    flipping = None if a.steady or a.cycles >= settings.min_cycles else settled_by_flips(t, theta, settings)
    if flipping is not None:
        a = flipping
    p = a.period
    t_settle = a.t_settle if np.isfinite(a.t_settle) else (t[-1] if t.size else np.nan)
    lab = None
    if "V_psi" in series and "V_L" in series:
        lab = np.asarray(series["V_psi"], dtype=float) + np.asarray(series["V_L"], dtype=float)
    contrast = float("nan")
    if "psi_min" in series and "psi_max" in series:
        contrast = _settled_mean(t, np.asarray(series["psi_max"], dtype=float)
                                 - np.asarray(series["psi_min"], dtype=float), t_settle)
        if contrast < MIXED:
            lab = None          # a mixture that did not separate (e.g. psi_bar outside the spinodal):
                                # the velocity of its decaying first mode means nothing
    tt = series.get("tank_treading_velocity")
    v_tt = abs(_settled_mean(t, None if tt is None else np.asarray(tt, dtype=float), t_settle))
    no_position = ""
    if lab is not None and v_tt > 0:
        settled = lab[t >= t_settle]
        undefined = float(np.mean(~np.isfinite(settled))) if settled.size else 0.0
        spread = float(np.std(settled[np.isfinite(settled)])) / v_tt if np.isfinite(settled).sum() > 1 else 0.0
        if undefined > UNDEFINED or spread > NOISY:
            if np.isfinite(contrast):      # psi separated (else: no pattern at all, e.g. psi = 0)
                no_position = ("the pattern has no position (the psi-weighted circular mean of alpha vanishes: "
                               "a two-fold symmetric pattern; its velocity is "
                               + (f"undefined in {undefined:.0%} of the samples)" if undefined > UNDEFINED
                                  else f"noise, spread {spread:.3g} tank-treading speeds)"))
            lab = None
    v_lab = _settled_mean(t, lab, t_settle)
    speed = abs(v_lab) / v_tt if np.isfinite(v_lab) and v_tt > 0 else float("nan")

    def cycles() -> float:
        """Settled periods of the period in use (a tumbling one may replace theta's own)."""
        return a.settled_span / p.period if np.isfinite(p.period) and p.period > 0 else 0.0

    def verdict(regime: str, reason: str) -> Classification:
        return Classification(regime, reason, a.t_settle, p.period, p.error, cycles(), a.mean,
                              a.mean_error, a.minimum, a.amplitude, a.drift, speed, p.crossing_period)

    duration = float(t[-1] - t[0]) if t.size else 0.0
    if t.size < settings.min_samples:
        return verdict(UNDECIDED, f"too short: {t.size} samples (at least {settings.min_samples} needed)")
    if not a.steady and not np.isfinite(p.period):
        tail = theta[-max(theta.size // 4, 2):]
        return verdict(UNDECIDED, f"not settled: theta still changes by {np.ptp(tail):.2g} rad over the last "
                                  "quarter of the record, and no period repeats in it; run longer")
    if not np.isfinite(a.t_settle):
        return verdict(UNDECIDED, "not settled: theta never stays within its final band")
    pattern = _pattern_words(speed, settings)
    if a.steady:
        if a.settled_span < settings.min_settled_fraction * duration:
            return verdict(UNDECIDED, f"not settled: theta steady only from t = {a.t_settle:.4g} "
                                      f"(last {a.settled_span / duration:.0%} of the record; run longer)")
        if np.isfinite(speed) and speed > settings.pattern_tol:
            return verdict(UNDECIDED, f"theta steady at {a.mean:.4f} but the pattern {pattern}")
        return verdict(TT, f"theta steady at {a.mean:.4f} rad (within {a.tolerance:.1e}) from "
                           f"t = {a.t_settle:.4g}; " + (f"the pattern {pattern}" if np.isfinite(speed)
                                                        else no_position or _no_pattern(contrast)))
    band = max(a.tolerance, settings.rel_tol * 2 * a.amplitude)
    if abs(a.drift) > band:
        return verdict(UNDECIDED, f"theta still drifting: its one-period mean moves by {a.drift:.2g} rad "
                                  f"after t = {a.t_settle:.4g}; run longer")
    if p.agree is False:
        return verdict(UNDECIDED, f"ambiguous period: autocorrelation {p.period:.5g}, mid-line crossings "
                                  f"{p.crossing_period:.5g}")
    if a.cycles < settings.min_cycles:
        return verdict(UNDECIDED, f"only {a.cycles:.1f} settled periods of {p.period:.4g} "
                                  f"(at least {settings.min_cycles:g}); run longer")
    irregular = ""
    if a.minimum < 0:
        settled = t >= a.t_settle
        flips = flip_period(t[settled], theta[settled])
        if np.isfinite(flips.period) and flips.agree is not False:
            p = flips
        if flipping is not None:
            # flip times that jitter add up like a random walk, which a line fitted through them does not
            # see: the mean interval, first to last flip, is known to the intervals' spread over the root
            # of their number (and a sample interval over the span)
            times = t[settled][flip_indices(theta[settled])]
            intervals = np.diff(times)
            mean = (times[-1] - times[0]) / intervals.size
            p = replace(p, error=max(p.error, float(intervals.std(ddof=1) / np.sqrt(intervals.size))
                                     + abs(p.period - mean) + (t[1] - t[0]) / (times[-1] - times[0])))
            irregular = (f"; settled by its flips (theta's sampled extremes jitter), "
                         f"{intervals.min():.4g} to {intervals.max():.4g} apart")
    periodic = (f"period {p.period:.5g} +- {p.error:.1g} ({cycles():.0f} cycles after t = {a.t_settle:.3g}), "
                f"amplitude {a.amplitude:.3g} rad")
    if a.minimum < 0:
        count = int(flip_indices(theta[t >= a.t_settle]).size)
        if count:
            return replace(verdict(TU, f"theta flips: min {a.minimum:.3f} < 0, {count} flips through +-pi/2; "
                                       f"{periodic}{irregular}"), flips=float(count))
        return replace(verdict(TU, f"theta swings below 0 without flipping: min {a.minimum:.3f} < 0 but never "
                                   f"through +-pi/2 ({SWINGING}); {periodic}"), flips=0.0)
    if np.isfinite(speed) and speed > settings.pattern_tol:
        found = verdict(PT, f"the pattern {pattern}; theta oscillates, min {a.minimum:.3f} > 0; {periodic}")
        if "E_bending" in series:
            gap, gap_err = bending_gap(t, series["E_bending"], p.period, a.t_settle)
            found = replace(found, bending_gap=gap, bending_gap_err=gap_err)
        return found
    what = (f"the pattern {pattern}" if np.isfinite(speed) else no_position
            or f"there is {_no_pattern(contrast)}")
    return verdict(UNDECIDED, f"theta oscillates ({periodic}) but {what}")


def flip_indices(theta: np.ndarray) -> np.ndarray:
    """Samples after which the folded angle jumps by more than pi / 2: the flips of a tumbling vesicle."""
    return np.nonzero(np.abs(np.diff(np.asarray(theta, dtype=float))) > 0.5 * np.pi)[0]


def settled_by_flips(t: np.ndarray, theta: np.ndarray, settings: AnalysisSettings) -> SignalAnalysis | None:
    """Settling of a flipping vesicle judged on its flip intervals, its period on sin 2 theta.

    The folded theta has its extremes at the flip, between two samples: where the flips do not keep a
    whole number of samples apart, the sampled extremes jitter by more than the settling band, and theta
    never settles (the authors' start at Delta = 2.3, S = 5, psi_bar = 0.48: flips 2.40-2.70 apart, the
    sampled maxima 1.45-1.57, settled only from the last flip). Nor can sin 2 theta's envelope tell, as
    it swings through +-1 at every flip whatever the period does. The flips settle from the first one
    after which the intervals between them show no linear trend beyond twice its standard error (at
    least 2 ``min_cycles`` intervals left); the period comes from sin 2 theta
    over them (:func:`flip_period`). None where no such flip exists. theta's extremes and mean are over
    the settled part; its drift and the error of its mean are not measured (nan).
    """
    t, theta = np.asarray(t, dtype=float), np.asarray(theta, dtype=float)
    times = t[flip_indices(theta)]
    half = max(int(np.ceil(settings.min_cycles)), 2)
    for first in range(max(times.size - 2 * half, 0)):
        intervals = np.diff(times[first:])
        k = np.arange(intervals.size) - 0.5 * (intervals.size - 1)
        slope = k @ intervals / (k @ k)                     # the intervals' linear trend, per flip
        scatter = intervals - intervals.mean() - slope * k
        error = np.sqrt(scatter @ scatter / (intervals.size - 2) / (k @ k))
        if abs(slope) <= 2.0 * error + (t[1] - t[0]) / (k @ k) ** 0.5:
            break
    else:
        return None
    t_settle = times[first]
    after = t >= t_settle
    period = flip_period(t[after], theta[after])
    if not np.isfinite(period.period):
        return None
    settled = theta[after]
    return SignalAnalysis(float(t_settle), float(t[-1] - t_settle), False, settings.abs_tol, float("nan"),
                          float(settled.mean()), float(settled.min()), float(settled.max()),
                          float(0.5 * np.ptp(settled)), float("nan"), period)


def flip_period(t: np.ndarray, theta: np.ndarray) -> PeriodEstimate:
    """The period of a vesicle whose inclination goes through +-pi/2, from sin 2 theta.

    The folded angle jumps by pi at every flip, between two samples, so its crossings fall on the
    sample grid: a flip period near a whole number of samples (psi_bar = 0.5, Delta = 0.94, S = 5:
    355 sample intervals) came out 1e-3 off with an error of 2e-5. sin 2 theta goes through the
    fold continuously and has the flip period."""
    return estimate_period(np.asarray(t, dtype=float), np.sin(2.0 * np.asarray(theta, dtype=float)))


def _no_pattern(contrast: float) -> str:
    if np.isfinite(contrast):
        return f"no phase pattern (psi stays mixed: max - min = {contrast:.2g})"
    return "no phase pattern"


def _pattern_words(speed: float, settings: AnalysisSettings) -> str:
    if not np.isfinite(speed):
        return "is not defined"
    if speed > settings.pattern_tol:
        return f"moves in the lab frame at {speed:.3g} of the tank-treading speed"
    return f"is fixed in the lab frame ({speed:.1e} of the tank-treading speed)"
