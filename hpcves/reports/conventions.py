"""CF metadata of the Datasets hpcves hands out (``open_case``, ``open_campaign``, the xarray engine).

CF-1.11 (https://cfconventions.org): every variable a ``long_name`` short enough to label a plot's axis
(xarray's plots do), its whole description in ``comment`` where that says more, and ``units`` where a
quantity has them ("rad" for angles; the model's quantities are dimensionless, and CF lets their
units be left out -- "1" would label every axis "[1]"); categorical results as a string variable
for reading and an integer
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


#: axis-length long_names of the sweepable parameters (model/params.PARAMETER_NAMES: their descriptions)
PARAMETER_SHORT = {"shear_rate": "shear rate S", "psi_bar": "mean composition psi_bar",
                   "excess_length": "excess length Delta", "B2": "bending rigidity B2",
                   "viscosity_ratio": "viscosity ratio lambda"}


def parameter_attrs(key: str) -> dict:
    """long_name and description of a sweepable physics parameter (dimensionless: no units)."""
    return described(PARAMETER_NAMES[key].long_name, "1", PARAMETER_SHORT[key])


def described(description: str, units: str, short: str | None = None) -> dict:
    """CF attributes of a variable: ``short`` (else ``description``) as long_name, the description as
    comment where it says more, units unless dimensionless ("1")."""
    attrs = {"long_name": short or description}
    if short and short != description:
        attrs["comment"] = description
    if units != "1":
        attrs["units"] = units
    return attrs


#: axis-length long_names of the series (run/diagnostics.SERIES_ATTRS holds their descriptions)
SERIES_NAMES = {
    "t": "time t", "theta": "inclination theta", "area_error": "relative area error",
    "length_error": "relative length error", "E_bending": "bending energy E_b", "E_phase": "line energy",
    "centroid": "centroid", "tension_min": "minimum tension", "tension_mean": "mean tension",
    "tension_max": "maximum tension", "V_psi": "phase-pattern velocity V_psi", "V_L": "membrane velocity V_L",
    "phase_position": "phase position", "psi_min": "minimum of psi", "psi_max": "maximum of psi",
    "area_correction": "summed area correction", "tank_treading_velocity": "tank-treading velocity",
    "stretching": "stretching residual", "tail_theta": "spectral tail of theta", "tail_psi": "spectral tail of psi",
    "N": "nodes N", "step": "time steps", "stresslet_xy": "stresslet Sigma_xy",
    "stresslet_normal": "stresslet Sigma_xx - Sigma_yy", "intrinsic_viscosity": "intrinsic viscosity [eta]",
    "normal_stress_coefficient": "normal-stress coefficient N1",
}
#: axis-length long_names of the snapshot fields (run/diagnostics.SNAPSHOT_ATTRS: their descriptions)
SNAPSHOT_NAMES = {
    "t": "snapshot time", "shift": "material shift a", "alpha": "arclength parameter alpha", "x": "x", "y": "y",
    "psi": "soft-phase concentration psi", "tension": "tension", "curvature": "curvature H",
    "velocity_x": "x velocity", "velocity_y": "y velocity",
}


#: (long_name for an axis, units, description) of every column of a case's analysis row (reports/analyze.py
#: COLUMNS) but the parameters, the case id and the categorical ones; and of a search's table
RESULT_ATTRS = {
    "t": ("time reached", "1", "time the case reached"),
    "t_end": ("end time", "1", "time the case was to run to"),
    "rtol": ("step tolerance rtol", "1", "relative tolerance of the adaptive time step (NaN: fixed step)"),
    "N": ("nodes N", "1", "number of nodes (where N adapts, the largest the run took)"),
    "period": ("period T", "1", "period of the inclination theta (phase-treading, tumbling)"),
    "period_err": ("period error (statistical)", "1", "statistical uncertainty of the period"),
    "period_dt_err": ("period error (time step)", "1", "time-step discretisation error of the period"),
    "period_N_err": ("period error (grid)", "1", "spatial discretisation error of the period"),
    "theta_mean": ("mean inclination", "rad", "mean inclination over the settled part"),
    "theta_mean_err": ("mean inclination error (statistical)", "rad",
                       "statistical uncertainty of the mean inclination"),
    "theta_mean_dt_err": ("mean inclination error (time step)", "rad",
                          "time-step discretisation error of the mean inclination"),
    "theta_mean_N_err": ("mean inclination error (grid)", "rad",
                         "spatial discretisation error of the mean inclination"),
    "theta_min": ("minimum inclination", "rad", "minimum inclination over the settled part"),
    "theta_amplitude": ("inclination amplitude", "rad", "amplitude of the inclination over the settled part"),
    "t_settle": ("settling time", "1", "time from which the motion is settled"),
    "cycles": ("settled periods", "1", "settled periods in the record"),
    "pattern_speed": ("pattern speed", "1", "speed of the phase pattern in the lab frame over the tank-treading speed"),
    "theta_drift": ("inclination drift", "rad", "drift of the inclination over the settled part"),
    "period_crossings": ("period from crossings", "1",
                         "the period from the crossings of the mean (a check of the period)"),
    "bending_gap": ("bending-energy gap", "1", "bending-energy gap Delta E_b: max - min of E_b over a period"),
    "bending_gap_err": ("bending-energy gap error", "1", "uncertainty of the bending-energy gap"),
    "flips": ("flips", "1", "flips of the inclination through +-pi/2 in the settled part of a TU case; 0 where "
              "theta swings below 0 without flipping (swinging); NaN for the other regimes"),
    "intrinsic_viscosity": ("intrinsic viscosity [eta]", "1",
                            "settled mean of the intrinsic viscosity [eta] = Sigma_xy / (S A)"),
    "intrinsic_viscosity_err": ("[eta] error (statistical)", "1", "statistical uncertainty of the mean [eta]"),
    "intrinsic_viscosity_dt_err": ("[eta] error (time step)", "1",
                                   "time-step discretisation error of the mean [eta]"),
    "intrinsic_viscosity_N_err": ("[eta] error (grid)", "1", "spatial discretisation error of the mean [eta]"),
    "intrinsic_viscosity_amplitude": ("[eta] amplitude", "1", "half the range of [eta] over the settled part"),
    "normal_stress_coefficient": ("normal-stress coefficient N1", "1",
                                  "settled mean of the first normal-stress coefficient N1 = "
                                  "(Sigma_xx - Sigma_yy) / (S A)"),
    "normal_stress_coefficient_err": ("N1 error (statistical)", "1", "statistical uncertainty of the mean N1"),
    "normal_stress_coefficient_dt_err": ("N1 error (time step)", "1", "time-step discretisation error of the mean N1"),
    "normal_stress_coefficient_N_err": ("N1 error (grid)", "1", "spatial discretisation error of the mean N1"),
    "normal_stress_coefficient_amplitude": ("N1 amplitude", "1", "half the range of N1 over the settled part"),
    "soft_domains": ("soft domains", "1", "soft domains (arcs with psi > 1/2) of the settled pattern"),
    "domains_on_tips": ("soft domains on tips", "1", "soft domains holding one of the two tips"),
    "two_fold": ("two-fold pattern", "1", "1 where the settled pattern is two-fold symmetric, else 0"),
    "topology_steady": ("steady topology", "1",
                        "1 where the pattern's topology is the same in every snapshot read, else 0"),
    "S_C": ("critical shear rate S_C", "1", "critical shear rate: best estimate inside the bracket"),
    "lambda_C": ("critical viscosity ratio", "1", "critical viscosity ratio: best estimate inside the bracket"),
    "bracket_low": ("bracket's low end", "1", "largest tank-treading value of the search"),
    "bracket_high": ("bracket's high end", "1", "smallest phase-treading or tumbling value above it"),
}
assert set(TOPOLOGY_COLUMNS) <= set(RESULT_ATTRS)

TEXT_ATTRS = {
    "regime": {"long_name": "regime", "comment": "TT tank-treading, PT phase-treading, TU tumbling, or undecided"},
    "reason": {"long_name": "reason", "comment": "the evidence for the regime, in words"},
    "status": {"long_name": "status of the case", "comment": "one of " + ", ".join(STATUS_NAMES.values())},
    "S_C_from": {"long_name": "S_C found from", "comment": "how the best estimate of S_C was found"},
    "lambda_C_from": {"long_name": "lambda_C found from", "comment": "how the best estimate of lambda_C was found"},
}


def regime_flag(regimes) -> tuple:
    """(values, attrs) of ``regime_flag``: the regimes as CF flags (codes :data:`REGIME_FLAGS`)."""
    values = np.array([REGIME_FLAGS.get(str(r), 0) for r in regimes], dtype=np.int8)
    return values, {"long_name": "regime of the case",
                    "flag_values": np.array(list(REGIME_FLAGS.values()), dtype=np.int8),
                    "flag_meanings": " ".join(REGIME_MEANINGS[r] for r in REGIME_FLAGS)}


def status_flag(statuses) -> tuple:
    """(values, attrs) of ``status_flag``: the statuses as CF flags (the codes of the file; -1 damaged)."""
    codes = {**STATUS_FLAGS, "damaged": DAMAGED_FLAG}
    values = np.array([codes[s] for s in statuses], dtype=np.int8)
    return values, {"long_name": "status of the case",
                    "flag_values": np.array(list(codes.values()), dtype=np.int8),
                    "flag_meanings": " ".join(name.replace(" ", "_") for name in codes)}


def result_attrs(column: str) -> dict:
    """long_name and units of an analysis column (a parameter's, a result's, or a text column's)."""
    if column in SWEEPABLE:
        return parameter_attrs(column)
    if column in RESULT_ATTRS:
        short, units, description = RESULT_ATTRS[column]
        return described(description, units, short)
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
