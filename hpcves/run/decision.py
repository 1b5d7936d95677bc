"""Run until decided: stop a case once the classifier of ``hpcves analyze`` has decided it.

Pure: series in, a :class:`Decision` (or None) out. The runner asks at a fixed
cadence of samples (``run.decision_samples``), always right after a sample, with
every sample recorded so far, so a resumed run asks the same questions of the
same numbers and decides at the same step.

A case is decided when :func:`regimes.classify` -- the classification of
``hpcves analyze``, with the study's ``[analysis]`` thresholds -- says

* TT, and theta has been steady (and the pattern fixed) for at least
  ``run.decided_shear_times`` shear times 1/S since it settled;
* PT or TU, over at least ``run.decided_periods`` settled periods.

"undecided" never stops a case: it runs to t_end, which is then a cap.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hpcves.analysis.regimes import PT, TT, TU, AnalysisSettings, classify
from hpcves.model.params import RunControl

#: the series the classifier reads
SERIES = ("t", "theta", "V_psi", "V_L", "tank_treading_velocity", "psi_min", "psi_max")

#: regime codes of the ``decision`` dataset (0: not decided)
CODES = {TT: 1, PT: 2, TU: 3}
REGIMES_BY_CODE = {code: regime for regime, code in CODES.items()}


@dataclass(frozen=True)
class Decision:
    regime: str
    t: float                   # time of the last sample the decision used
    reason: str                # the classifier's evidence, and what made it enough

    def message(self) -> str:
        return f"decided {self.regime} at t = {self.t:.6g}: {self.reason}"


def decide(series: dict, shear_rate: float, run: RunControl,
           settings: AnalysisSettings = AnalysisSettings()) -> Decision | None:
    """The decision on the series so far, or None if they do not decide the case yet."""
    t = np.asarray(series["t"], dtype=float)
    if t.size < settings.min_samples:
        return None
    c = classify(series, settings)
    if c.regime == TT:
        if shear_rate <= 0:
            return None
        steady_for = (t[-1] - c.t_settle) * shear_rate
        if steady_for >= run.decided_shear_times:
            return Decision(TT, float(t[-1]), f"{c.reason}; steady for {steady_for:.0f} shear times "
                                              f"(run.decided_shear_times = {run.decided_shear_times:g})")
        return None
    if c.regime in (PT, TU) and c.cycles >= run.decided_periods:
        return Decision(c.regime, float(t[-1]), f"{c.reason}; {c.cycles:.0f} settled periods "
                                                f"(run.decided_periods = {run.decided_periods:g})")
    return None
