"""Discretisation error bars: how far a period or a mean inclination may be off for the time step.

An adaptive run (``numerics.rtol``) keeps each step's local error estimate below
(atol + rtol |y|) sqrt(rtol) (stepcontrol.py), which makes the global error
proportional to rtol (tolerance proportionality, measured in
tests/test_stepcontrol.py). The error of what ``hpcves analyze`` reads from
theta(t) then follows the same law, with constants measured by
analysis/error_rule.py over TT, PT and TU cases at rtol = 0.1 ... 0.003, at the
job files' sampling and at a sparse one (docs/error_rule.md):

    |T - T_exact| / T      <= PERIOD_PER_RTOL * rtol
    |theta - theta_exact|  <= INCLINATION_PER_RTOL * rtol    (rad)

beyond what the statistical errors of the estimates allow. The constants are
the largest measured ratios times a safety factor of 2. Two kinds of run get
no bar (nan, "not estimated"): a fixed-step run, whose error is found only by
rerunning at dt / 2 or with ``rtol``; and tumbling (theta flips), where the
tolerance picks the orbit the vesicle settles on: periods 1 % (rtol = 1e-2,
1e-3) and 0.1 % (1e-4) longer than at 1e-5, out of proportion to rtol
(docs/error_rule.md).

The spatial error (the grid N) follows the run's spectral tail instead: the largest
share of the top third of the Fourier modes of theta_tilde or psi over the settled
part of the run (the samples' tail_theta, tail_psi), with constants measured by
analysis/spatial_error.py against runs at N = 192 (docs/spatial_error.md):

    |T - T_exact| / T      <= PERIOD_PER_TAIL * tail
    |theta - theta_exact|  <= INCLINATION_PER_TAIL * tail    (rad)

again twice the largest measured ratios; none for tumbling, for records without
the tails (files from before them), and for a tail beyond run.max_spectral_tail's
default (TAIL_RULED_UP_TO), where the measured ratios scatter up to 2.3.
"""
from __future__ import annotations

import math

import numpy as np

#: relative period error per unit rtol: 2 x the largest ratio measured, 0.081 (docs/error_rule.md)
PERIOD_PER_RTOL = 0.17
#: error of the mean inclination in rad per unit rtol: 2 x the largest ratio measured, 0.0011
INCLINATION_PER_RTOL = 0.0025


#: How far the periodic orbit a tumbling run settles on moves with the numerics: its period was up to 1 %
#: longer at rtol = 1e-2 and 1e-3 than at 1e-5 (docs/error_rule.md), and 1.3 % apart at rtol = 1e-2 with
#: samples every 0.02 and 0.025 (Delta = 0.94, psi_bar = 0.48, S = 4: 4.7259 and 4.6644; steps land on
#: sample times). Not an error bar of one run -- the rule does not hold -- but how far two tumbling runs
#: may differ before they are different states (hpcves/reports/attractor_map.py).
TUMBLING_ORBIT_SPREAD = 0.015


#: relative period error per unit spectral tail: 2 x the largest ratio measured, 0.90 (PT at Delta = 1.6,
#: N = 48, tail 1.4e-2; 0.71 at N = 64, tail 1.8e-3; docs/spatial_error.md)
PERIOD_PER_TAIL = 1.8
#: error of the mean inclination in rad per unit spectral tail: 2 x the largest ratio measured, 1.07 (TT at
#: Delta = 2.3, N = 96)
INCLINATION_PER_TAIL = 2.2
#: the largest tail the rule holds at (run.max_spectral_tail's default): a run whose watch was loosened past it
#: gets no spatial bar -- the tests' phase-treading case at N = 32 (psi_bar = 0.3, S = 80, tail 1.0e-2) has a
#: period 2.3 % off, 2.3 times its tail, beyond what the rule covers
TAIL_RULED_UP_TO = 3e-3


def settled_tail(t, tail_theta, tail_psi, t_settle: float) -> float:
    """The largest spectral tail of theta_tilde or psi over the samples from t_settle on (all of them
    where t_settle is not known); nan without the series."""
    if tail_theta is None or len(tail_theta) == 0:
        return math.nan
    t = np.asarray(t)
    tails = np.asarray(tail_theta) if tail_psi is None else np.maximum(tail_theta, tail_psi)
    settled = t >= t_settle if math.isfinite(t_settle) else np.ones(t.size, bool)
    chosen = tails[settled] if settled.any() else tails
    chosen = chosen[np.isfinite(chosen)]
    return float(chosen.max()) if chosen.size else math.nan


def spatial_period_error(period: float, tail: float, flips: bool = False) -> float:
    """Spatial error bar of a period: PERIOD_PER_TAIL tail T; nan without the tail or a period, for a
    tail beyond TAIL_RULED_UP_TO, and for tumbling (as :func:`period_error`)."""
    if not (math.isfinite(tail) and math.isfinite(period)) or tail > TAIL_RULED_UP_TO or flips:
        return math.nan
    return PERIOD_PER_TAIL * tail * abs(period)


def spatial_inclination_error(theta_mean: float, tail: float, flips: bool = False) -> float:
    """Spatial error bar of a mean inclination: INCLINATION_PER_TAIL tail (rad); nan as above."""
    if not (math.isfinite(tail) and math.isfinite(theta_mean)) or tail > TAIL_RULED_UP_TO or flips:
        return math.nan
    return INCLINATION_PER_TAIL * tail


def period_error(period: float, rtol: float | None, flips: bool = False) -> float:
    """Discretisation error bar of a period: PERIOD_PER_RTOL rtol T.

    nan without rtol (a fixed-step run) or without a period, and for a motion whose theta flips
    (tumbling: min theta < 0), for which the rule does not hold (docs/error_rule.md).
    """
    if rtol is None or not math.isfinite(rtol) or not math.isfinite(period) or flips:
        return math.nan
    return PERIOD_PER_RTOL * rtol * abs(period)


def inclination_error(theta_mean: float, rtol: float | None, flips: bool = False) -> float:
    """Discretisation error bar of a mean inclination: INCLINATION_PER_RTOL rtol (rad); nan as for
    :func:`period_error`."""
    if rtol is None or not math.isfinite(rtol) or not math.isfinite(theta_mean) or flips:
        return math.nan
    return INCLINATION_PER_RTOL * rtol


#: error of the settled mean [eta] / N1 per unit rtol and per unit spectral tail: 2 x the largest ratios
#: measured over the TT and PT cases of theta's rules (docs/stress_error.md, analysis/stress_error.py):
#: per rtol 0.0227 and 0.0234 (PT at psi_bar = 0.5, S = 80), per tail 1.69 and 5.39 (TT at Delta = 2.3)
STRESS_PER_RTOL = {"intrinsic_viscosity": 0.046, "normal_stress_coefficient": 0.047}
STRESS_PER_TAIL = {"intrinsic_viscosity": 3.4, "normal_stress_coefficient": 11.0}


def stress_step_error(quantity: str, rtol: float | None, flips: bool = False) -> float:
    """Time-step error bar of the settled mean of a rheology series (``quantity``: "intrinsic_viscosity" or
    "normal_stress_coefficient"): STRESS_PER_RTOL rtol; nan as :func:`inclination_error` (a fixed step,
    tumbling)."""
    if rtol is None or not math.isfinite(rtol) or flips:
        return math.nan
    return STRESS_PER_RTOL[quantity] * rtol


def stress_grid_error(quantity: str, tail: float, flips: bool = False) -> float:
    """Grid error bar of the settled mean of a rheology series: STRESS_PER_TAIL tail; nan as
    :func:`spatial_inclination_error` (no tails, a tail beyond TAIL_RULED_UP_TO, tumbling)."""
    if not math.isfinite(tail) or tail > TAIL_RULED_UP_TO or flips:
        return math.nan
    return STRESS_PER_TAIL[quantity] * tail


def error_bar(row: dict, quantity: str) -> tuple[float, str]:
    """(statistical + time-step + spatial error of ``quantity`` ("period" or "theta_mean"), which dominates).

    They are added (not in quadrature: the discretisation errors are bounds, not spreads). Which
    dominates: "stat", "dt" or "N", followed by the parts not estimated: "stat, dt n/e" (a fixed
    step, tumbling), "dt, N n/e" (a record without the spectral tails).
    """
    stat = row.get(f"{quantity}_err", math.nan)
    parts = {"stat": stat if math.isfinite(stat) else 0.0}
    missing = []
    for name, key in (("dt", f"{quantity}_dt_err"), ("N", f"{quantity}_N_err")):
        value = row.get(key, math.nan)
        if math.isfinite(value):
            parts[name] = value
        else:
            missing.append(f"{name} n/e")
    dominant = max(parts, key=lambda name: (parts[name], name != "stat"))
    return sum(parts.values()), ", ".join([dominant] + missing)
