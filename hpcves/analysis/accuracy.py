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
(docs/error_rule.md). The spatial error (the grid N) is not
in these bars (docs/analysis.md says what is known of it).
"""
from __future__ import annotations

import math

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


def error_bar(row: dict, quantity: str) -> tuple[float, str]:
    """(statistical + discretisation error of ``quantity`` ("period" or "theta_mean"), which dominates).

    The two are added (not in quadrature: the discretisation error is a bound, not a spread).
    Which dominates: "dt" or "stat"; "stat, dt n/e" where the discretisation error is not
    estimated (a fixed step, tumbling).
    """
    stat, dt = row.get(f"{quantity}_err", math.nan), row.get(f"{quantity}_dt_err", math.nan)
    stat = stat if math.isfinite(stat) else 0.0
    if not math.isfinite(dt):
        return stat, "stat, dt n/e"
    return stat + dt, "dt" if dt >= stat else "stat"
