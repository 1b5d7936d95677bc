"""CF metadata of the Datasets hpcves hands out (``open_case``, ``open_campaign``, the xarray engine).

CF-1.11 (https://cfconventions.org): every variable a ``long_name`` and ``units`` ("1" for the
model's dimensionless quantities, "rad" for angles); categorical results as a string variable for reading and an integer
twin (``regime_flag``, ``status_flag``) carrying ``flag_values`` / ``flag_meanings``, the form CF
defines flags in; attribute names without dots; coordinates without missing values.
"""
from __future__ import annotations

import numpy as np

from hpcves.analysis.regimes import PT, TT, TU, UNDECIDED
from hpcves.model.params import PARAMETER_NAMES, SWEEPABLE
from hpcves.run.decision import CODES
from hpcves.run.store import STATUS_NAMES
from hpcves.run.verdict import TOPOLOGY_COLUMNS

CONVENTIONS = "CF-1.11"

#: the integer codes of the regimes: 0 undecided, and the codes run/decision.py stores for a decided run
REGIME_FLAGS = {UNDECIDED: 0, **CODES}
REGIME_MEANINGS = {UNDECIDED: "undecided", TT: "tank_treading", PT: "phase_treading", TU: "tumbling"}
#: a case's status: its code in the file, and a name without blanks (CF flag meanings are words)
STATUS_FLAGS = {name: code for code, name in STATUS_NAMES.items()}
DAMAGED_FLAG = -1                    # open_campaign: a case whose data could not be read


def parameter_attrs(key: str) -> dict:
    """long_name and units of a sweepable physics parameter."""
    return {"long_name": PARAMETER_NAMES[key].long_name, "units": "1"}


#: long_name and units of every column of a case's analysis row (reports/analyze.py COLUMNS) but the
#: parameters, the case id and the categorical ones
RESULT_ATTRS = {
    "t": ("time the case reached", "1"),
    "t_end": ("time the case was to run to", "1"),
    "rtol": ("relative tolerance of the adaptive time step (NaN: fixed step)", "1"),
    "N": ("number of nodes (where N adapts, the largest the run took)", "1"),
    "period": ("period of the inclination theta (phase-treading, tumbling)", "1"),
    "period_err": ("statistical uncertainty of the period", "1"),
    "period_dt_err": ("time-step discretisation error of the period", "1"),
    "period_N_err": ("spatial discretisation error of the period", "1"),
    "theta_mean": ("mean inclination over the settled part", "rad"),
    "theta_mean_err": ("statistical uncertainty of the mean inclination", "rad"),
    "theta_mean_dt_err": ("time-step discretisation error of the mean inclination", "rad"),
    "theta_mean_N_err": ("spatial discretisation error of the mean inclination", "rad"),
    "theta_min": ("minimum inclination over the settled part", "rad"),
    "theta_amplitude": ("amplitude of the inclination over the settled part", "rad"),
    "t_settle": ("time from which the motion is settled", "1"),
    "cycles": ("settled periods in the record", "1"),
    "pattern_speed": ("speed of the phase pattern in the lab frame over the tank-treading speed", "1"),
    "theta_drift": ("drift of the inclination over the settled part", "rad"),
    "period_crossings": ("the period from the crossings of the mean (a check of the period)", "1"),
    "bending_gap": ("bending-energy gap Delta E_b: max - min of E_b over a period", "1"),
    "bending_gap_err": ("uncertainty of the bending-energy gap", "1"),
    "soft_domains": ("soft domains (arcs with psi > 1/2) of the settled pattern", "1"),
    "domains_on_tips": ("soft domains holding one of the two tips", "1"),
    "two_fold": ("1 where the settled pattern is two-fold symmetric, else 0", "1"),
    "topology_steady": ("1 where the pattern's topology is the same in every snapshot read, else 0", "1"),
}
assert set(TOPOLOGY_COLUMNS) <= set(RESULT_ATTRS)

TEXT_ATTRS = {
    "regime": {"long_name": "regime: TT tank-treading, PT phase-treading, TU tumbling, or undecided"},
    "reason": {"long_name": "the evidence for the regime, in words"},
    "status": {"long_name": "status of the case: " + ", ".join(STATUS_NAMES.values())},
}


def regime_flag(regimes) -> tuple:
    """(values, attrs) of ``regime_flag``: the regimes as CF flags (codes :data:`REGIME_FLAGS`)."""
    values = np.array([REGIME_FLAGS.get(str(r), 0) for r in regimes], dtype=np.int8)
    return values, {"long_name": "regime of the case", "units": "1",
                    "flag_values": np.array(list(REGIME_FLAGS.values()), dtype=np.int8),
                    "flag_meanings": " ".join(REGIME_MEANINGS[r] for r in REGIME_FLAGS)}


def status_flag(statuses) -> tuple:
    """(values, attrs) of ``status_flag``: the statuses as CF flags (the codes of the file; -1 damaged)."""
    codes = {**STATUS_FLAGS, "damaged": DAMAGED_FLAG}
    values = np.array([codes[s] for s in statuses], dtype=np.int8)
    return values, {"long_name": "status of the case", "units": "1",
                    "flag_values": np.array(list(codes.values()), dtype=np.int8),
                    "flag_meanings": " ".join(name.replace(" ", "_") for name in codes)}


def result_attrs(column: str) -> dict:
    """long_name and units of an analysis column (a parameter's, a result's, or a text column's)."""
    if column in SWEEPABLE:
        return parameter_attrs(column)
    if column in RESULT_ATTRS:
        long_name, units = RESULT_ATTRS[column]
        return {"long_name": long_name, "units": units}
    return dict(TEXT_ATTRS.get(column, {"long_name": column.replace("_", " ")}))


def netcdf_attrs(attrs: dict) -> dict:
    """``attrs`` as netCDF takes them: names without dots (``numerics.N`` -> ``numerics_N``), booleans
    as 0/1, None as ""."""
    out = {}
    for key, value in attrs.items():
        if isinstance(value, (bool, np.bool_)):
            value = int(value)
        elif value is None:
            value = ""
        out[key.replace(".", "_")] = value
    return out
