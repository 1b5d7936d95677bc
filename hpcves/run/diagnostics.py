"""What a run records: scalar samples (time series), snapshots, and health checks.

Pure functions of the solver's state and the rates at that state.

Conventions
-----------
* ``theta`` -- inclination of the long principal axis of the enclosed region's
  second-moment tensor against the x axis, in (-pi/2, pi/2].
* ``tension_*`` -- the Lagrange multiplier Lambda of local inextensibility.
  The solver determines the effective tension Lambda + sigma, sigma =
  (a0/eps)(g - eps^2/2 psi_s^2) being the line-energy part; it is subtracted.
* ``phase_position`` -- circular mean of the material label alpha weighted by
  psi, in [0, 1).
* ``tail_theta``, ``tail_psi`` -- the share of the top third of the Fourier
  modes in the variation of theta_tilde and psi (spectral.spectral_tail): the
  resolution watch; above ``run.max_spectral_tail`` the run stops as
  under-resolved (where N adapts: once it is N_max).
* ``N`` -- the nodes of the run at the sample (numerics.N, or where it adapts the
  N it has grown or shrunk to; resolution.py).
* ``step`` -- the steps taken up to the sample (with ``N``: the steps each grid took).
* ``stresslet_xy``, ``stresslet_normal`` -- Sigma_xy and Sigma_xx - Sigma_yy of the vesicle's
  stresslet (model/rheology.py), from the force and velocity at the sample: no extra flow solve.
* ``intrinsic_viscosity``, ``normal_stress_coefficient`` -- [eta] = Sigma_xy / (S A) and
  N1 = (Sigma_xx - Sigma_yy) / (S A), A the enclosed area.
* ``V_psi`` -- velocity (arclength per time) of the phase pattern relative to
  the material: L d(phase_position)/dt.
* ``V_L`` -- velocity of the material point alpha = 0 relative to the point
  where the long axis (the ray from the centroid at angle theta) meets the
  membrane, measured along the membrane. ``V_psi + V_L`` is the velocity of
  the phase pattern in the lab frame: zero for tank-treading.
All rates are instantaneous (from the velocity field), not differences of samples.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hpcves.model import geometry, phasefield, rheology
from hpcves.model.forces import bending_energy, bending_force, phase_energy, tension_force
from hpcves.numerics.spectral import resolution_needed, spectral_tail
from hpcves.solver.timestepping import EMPTY, EMPTY_SPECTRUM, Rates, Solver, State, compiled_kernels

#: Names of the scalar time series, in file order; ``centroid`` has two columns.
SERIES = ("t", "theta", "area_error", "length_error", "E_bending", "E_phase", "centroid",
          "tension_min", "tension_mean", "tension_max", "V_psi", "V_L", "phase_position",
          "psi_min", "psi_max", "area_correction", "tank_treading_velocity", "stretching",
          "tail_theta", "tail_psi", "N", "step",
          "stresslet_xy", "stresslet_normal", "intrinsic_viscosity", "normal_stress_coefficient")

#: the stress the vesicle adds to the suspension (model/rheology.py): recorded since case format 7
RHEOLOGY_SERIES = ("stresslet_xy", "stresslet_normal", "intrinsic_viscosity", "normal_stress_coefficient")

#: series added after files of format 3 were first written: a case without them still reads
OPTIONAL_SERIES = ("tail_theta", "tail_psi", "N", "step") + RHEOLOGY_SERIES

#: Names of the snapshot fields (one value per node).
SNAPSHOT_FIELDS = ("x", "y", "psi", "tension", "curvature", "velocity_x", "velocity_y")

#: (long_name, units) of every series and snapshot field: the attributes of its dataset (CF style:
#: "1" is dimensionless -- the model is, with eta = B1 = 1 and the lengths of the initial ellipse of
#: L = 2.6442, SPEC section 1)
SERIES_ATTRS = {
    "t": ("time", "1"),
    "theta": ("inclination of the long principal axis against the flow direction", "rad"),
    "area_error": ("relative error of the enclosed area", "1"),
    "length_error": ("relative error of the membrane length", "1"),
    "E_bending": ("bending energy 1/2 int B(psi) H^2 ds", "1"),
    "E_phase": ("line energy (a0/eps) int (g(psi) + eps^2/2 psi_s^2) ds", "1"),
    "centroid": ("centroid of the enclosed region (x, y)", "1"),
    "tension_min": ("minimum over the membrane of the tension Lambda", "1"),
    "tension_mean": ("mean over the membrane of the tension Lambda", "1"),
    "tension_max": ("maximum over the membrane of the tension Lambda", "1"),
    "V_psi": ("velocity of the phase pattern relative to the material, along the membrane", "1"),
    "V_L": ("velocity of the material point alpha = 0 relative to the long axis, along the membrane", "1"),
    "phase_position": ("circular mean of the material label weighted by psi", "1"),
    "psi_min": ("minimum of the soft-phase concentration psi", "1"),
    "psi_max": ("maximum of the soft-phase concentration psi", "1"),
    "area_correction": ("running sum of the relative area corrections of the projection", "1"),
    "tank_treading_velocity": ("mean tangential membrane velocity", "1"),
    "stretching": ("maximum of s . du/ds over the membrane (inextensibility residual)", "1"),
    "tail_theta": ("share of the top third of the Fourier modes in the variation of theta_tilde", "1"),
    "tail_psi": ("share of the top third of the Fourier modes in the variation of psi", "1"),
    "N": ("number of nodes the run had (numerics.N, or where N adapts the N it had grown or shrunk to)", "1"),
    "step": ("time steps taken from t = 0 up to the sample", "1"),
    "stresslet_xy": ("shear component Sigma_xy of the vesicle's stresslet", "1"),
    "stresslet_normal": ("normal-stress difference Sigma_xx - Sigma_yy of the vesicle's stresslet", "1"),
    "intrinsic_viscosity": ("intrinsic viscosity [eta] = Sigma_xy / (S A)", "1"),
    "normal_stress_coefficient": ("first normal-stress coefficient N1 = (Sigma_xx - Sigma_yy) / (S A)", "1"),
}
SNAPSHOT_ATTRS = {
    "t": ("time of the snapshot", "1"),
    "shift": ("material shift a(t): the node at alpha carries the material label alpha - a", "1"),
    "alpha": ("equal-arclength parameter of the node, s / L from the tracking point (node j: j / N)", "1"),
    "x": ("x of the membrane node", "1"),
    "y": ("y of the membrane node", "1"),
    "psi": ("soft-phase concentration psi (1 = soft, 0 = hard)", "1"),
    "tension": ("tension Lambda (line-energy part removed)", "1"),
    "curvature": ("curvature H", "1"),
    "velocity_x": ("x velocity of the membrane node", "1"),
    "velocity_y": ("y velocity of the membrane node", "1"),
}


@dataclass(frozen=True)
class Health:
    ok: bool
    reason: str = ""
    under_resolved: bool = False     # the failure is the resolution, not the dynamics


HEALTHY = Health(True)
#: the arrays the per-step check finds non-finite values in, in the order soundness tests them
_SOUND = ("theta", "psi", "prev_rate_theta", "prev_rate_psi")


def tension(state: State, rates: Rates, solver: Solver) -> np.ndarray:
    """Lambda = Lambda~ - sigma at the nodes."""
    phys = solver.case.physics
    sigma = phasefield.line_tension(state.psi, rates.psi_s, phys.a0, phys.epsilon)
    return rates.flow.tension_eff - sigma


def phase_position(psi: np.ndarray) -> complex:
    """sum_j psi_j e^{2 pi i alpha_j}: its argument / 2 pi is the psi-weighted circular mean of alpha."""
    return complex(np.fft.fft(psi)[-1])            # = sum psi e^{+2 pi i j/N}


def axis_point(solver: Solver, shape, moments: geometry.Moments) -> float:
    """Node coordinate alpha_a in [0, 1) where the ray centroid + r e^{i theta} meets the membrane."""
    sp = solver.sp
    rot = np.exp(-1j * moments.inclination)
    w = (shape.z - moments.centroid) * rot
    g = w.imag
    N = g.size
    candidates = [j for j in range(N) if w[j].real > 0 and w[(j + 1) % N].real > 0
                  and g[j] <= 0.0 < g[(j + 1) % N]]
    if not candidates:                                 # degenerate: pick the node closest to the ray
        j = int(np.argmax(w.real - 10 * np.abs(g)))
        return j / N
    j = candidates[0]
    alpha = (j + g[j] / (g[j] - g[(j + 1) % N])) / N    # linear guess, then Newton on the interpolant
    for _ in range(8):
        z_a, dz_a = sp.interpolate(np.stack([shape.z, shape.tangent * sp.length]), alpha)
        value = ((z_a - moments.centroid) * rot).imag
        slope = (dz_a * rot).imag
        step = value / slope
        alpha -= step
        if abs(step) < 1e-14:
            break
    return float(alpha % 1.0)


def sample(solver: Solver, state: State, rates: Rates) -> dict:
    """One row of every time series (see :data:`SERIES`); with the compiled engine its numbers come
    from one kernel (compiled.sample_values, the same formulas), else from the numpy ones below."""
    if solver.engine == "compiled":
        return _compiled_sample(solver, state, rates)
    sp, phys = solver.sp, solver.case.physics
    shape, flow = rates.shape, rates.flow
    m = geometry.moments(shape.z, shape.normal, sp.length)
    length = geometry.length_of(shape.z, sp)
    lam = tension(state, rates, solver)

    # phase pattern relative to the material: psi is held at the nodes, node alpha
    # carries label alpha - a, so the material circular mean is the nodes' one minus a;
    # rates.psi (psi_t without the advection) is the material rate, seen at the nodes
    Z = phase_position(state.psi)
    dZ = phase_position(rates.psi)
    if abs(Z) > 1e-12 * sp.N:
        position = (np.angle(Z) / (2 * np.pi) - state.shift) % 1.0
        V_psi = sp.length * float(np.imag(dZ / Z)) / (2 * np.pi)
    else:
        position, V_psi = np.nan, np.nan

    # material point alpha = 0 relative to the long axis
    u = flow.velocity
    normal_velocity = np.real(np.conj(shape.normal) * u)
    dA, dc, dIxx, dIxy, dIyy = geometry.moment_rates(shape.z, shape.normal, normal_velocity, sp.length, m)
    a_axis = axis_point(solver, shape, m)
    dphi = ((m.Ixx - m.Iyy) * dIxy - m.Ixy * (dIxx - dIyy)) / ((m.Ixx - m.Iyy) ** 2 + 4 * m.Ixy**2)
    V = rates.mean_tangential_velocity
    node_velocity = u - V * shape.tangent
    z_a, dz_a, w_a = sp.interpolate(np.stack([shape.z, shape.tangent * sp.length, node_velocity]), a_axis)
    rot = np.exp(-1j * m.inclination)
    da_axis = -((w_a - dc - 1j * dphi * (z_a - m.centroid)) * rot).imag / (dz_a * rot).imag
    V_L = V - sp.length * da_axis

    return {
        "t": solver.time(state),
        "theta": m.inclination,
        "area_error": (m.area - solver.area0) / solver.area0,
        "length_error": (length - sp.length) / sp.length,
        "E_bending": bending_energy(shape.curvature, state.psi, phys, sp.length),
        "E_phase": phase_energy(state.psi, rates.psi_s, phys, sp.length),
        "centroid": (m.centroid.real, m.centroid.imag),
        "tension_min": float(lam.min()),
        "tension_mean": float(lam.mean()),
        "tension_max": float(lam.max()),
        "V_psi": V_psi,
        "V_L": float(V_L),
        "phase_position": position,
        "psi_min": float(state.psi.min()),
        "psi_max": float(state.psi.max()),
        "area_correction": state.area_correction,
        "tank_treading_velocity": V,
        "stretching": float(np.abs(flow.stretching(shape.tangent, sp)).max()),
        "tail_theta": spectral_tail(sp.fft.rfft(state.theta), sp.N),
        "tail_psi": 0.0 if phys.homogeneous else spectral_tail(rates.psi_hat, sp.N),
        "N": float(sp.N),
        "step": float(state.step),
        **stress(solver, state, rates, m.area),
    }


def stress(solver: Solver, state: State, rates: Rates, area: float) -> dict:
    """The rheology series (:data:`RHEOLOGY_SERIES`) at the sample: the stresslet of the force
    f = f_b + d(Lambda~ s)/ds and the velocity the rates hold (model/rheology.py)."""
    sp, phys, shape = solver.sp, solver.case.physics, rates.shape
    force = bending_force(shape.curvature, state.psi, rates.psi_s, shape.tangent, phys, sp) \
        + tension_force(rates.flow.tension_eff, shape.tangent, sp)
    shear, normal = rheology.stresslet(shape.z, shape.normal, force, rates.flow.velocity, sp.length,
                                       phys.viscosity_ratio)
    eta, n1 = rheology.coefficients(shear, normal, phys.shear_rate, area)
    return {"stresslet_xy": shear, "stresslet_normal": normal, "intrinsic_viscosity": eta,
            "normal_stress_coefficient": n1}


def _compiled_sample(solver: Solver, state: State, rates: Rates) -> dict:
    ops, physics, _, _ = solver._operators()
    shape, flow = rates.shape, rates.flow
    (theta, area, length, E_bending, E_phase, centroid_x, centroid_y, tension_min, tension_mean, tension_max,
     V_psi, V_L, phase_position, psi_min, psi_max, stretching, tail_theta, tail_psi) = \
        compiled_kernels().sample_values(
            state.theta, state.psi, float(state.shift), shape.z, shape.tangent, shape.curvature, flow.velocity,
            flow.tension_eff, rates.psi_s, rates.psi, EMPTY_SPECTRUM if rates.psi_hat is None else rates.psi_hat,
            float(rates.mean_tangential_velocity), solver.case.physics.homogeneous, ops[3], solver.node_phase,
            physics).tolist()                                   # in the order of compiled.SAMPLE
    area0, length0 = solver.area0, solver.sp.length
    return {
        "t": solver.time(state),
        "theta": theta,
        "area_error": (area - area0) / area0,
        "length_error": (length - length0) / length0,
        "E_bending": E_bending,
        "E_phase": E_phase,
        "centroid": (centroid_x, centroid_y),
        "tension_min": tension_min,
        "tension_mean": tension_mean,
        "tension_max": tension_max,
        "V_psi": V_psi,
        "V_L": V_L,
        "phase_position": phase_position,
        "psi_min": psi_min,
        "psi_max": psi_max,
        "area_correction": state.area_correction,
        "tank_treading_velocity": rates.mean_tangential_velocity,
        "stretching": stretching,
        "tail_theta": tail_theta,
        "tail_psi": tail_psi,
        "N": float(solver.sp.N),
        "step": float(state.step),
        **stress(solver, state, rates, area),
    }


def inclination(solver: Solver, state: State, rates: Rates) -> float:
    """The sample's ``theta`` (bitwise what :func:`sample` records, by either engine)."""
    if solver.engine == "compiled":
        return _compiled_sample(solver, state, rates)["theta"]
    return geometry.moments(rates.shape.z, rates.shape.normal, solver.sp.length).inclination


def snapshot(solver: Solver, state: State, rates: Rates) -> dict:
    """Fields at the nodes (see :data:`SNAPSHOT_FIELDS`), plus t and the material shift a."""
    shape, u = rates.shape, rates.flow.velocity
    return {
        "t": solver.time(state),
        "shift": state.shift,
        "x": shape.z.real.copy(),
        "y": shape.z.imag.copy(),
        "psi": state.psi.copy(),
        "tension": tension(state, rates, solver),
        "curvature": shape.curvature.copy(),
        "velocity_x": u.real.copy(),
        "velocity_y": u.imag.copy(),
    }


def _overshoot_context(solver: Solver, state: State) -> str:
    """Where psi overshot, when it is the soft phase pulled past 1 at a sharp tip.

    B(psi) = (1 - psi) B1 + psi B2 vanishes at psi = B1 / (B1 - B2) (1.11 for
    B2 = 0.1); seen at Delta = 2.3 (S <= 20; at N = 128 also S = 320), where
    psi's maximum sits at the curvature maximum and both grow together
    (docs/numerics.md).
    """
    phys = solver.case.physics
    j = int(np.argmax(state.psi))
    curvature = np.abs(solver.shape(state).curvature)
    if phys.bending_law != "linear" or phys.B2 >= phys.B1 or curvature[j] < 0.5 * curvature.max():
        return ""
    return (f"; the maximum of psi sits where |H| = {curvature[j]:.3g} (largest |H| {curvature.max():.3g}): "
            f"the soft phase is drawn past 1 at a sharp tip, towards psi = {phys.B1 / (phys.B1 - phys.B2):.3g} "
            "where the linear B(psi) of the model vanishes")


#: above this rtol the step's error estimate has let grid-scale error grow in cases N resolves
LOOSE_RTOL = 1e-3


def _loose_step_hint(numerics) -> str:
    """The other cause of a growing spectral tail: a loose step tolerance.

    The step's error estimate weighs the few top Fourier modes little, so at
    rtol = 1e-2 steps that amplify them are accepted, and cases that N resolves
    at rtol = 1e-3 stop as under-resolved (measured in docs/numerics.md,
    "Adaptive time step"). A larger N at the same rtol is then the dearer cure.
    """
    if numerics.adaptive and numerics.rtol > LOOSE_RTOL:
        return (f", unless the step lets grid-scale error grow: at numerics.rtol = {numerics.rtol:g} "
                f"try rtol = {LOOSE_RTOL:g} at this N first")
    return ""


def health(solver: Solver, state: State, row: dict | None, last_correction: float = 0.0) -> Health:
    """Is the run still sane? NaN, area/length error, psi range (RunControl bounds)."""
    run = solver.case.run
    # prev_theta / prev_psi are the previous state's arrays, checked one step earlier
    names = _SOUND
    if solver.engine == "compiled":
        rate_theta, rate_psi = state.prev_rate_theta, state.prev_rate_psi
        which, lo, hi = compiled_kernels().soundness(state.theta, state.psi,
                                                     EMPTY if rate_theta is None else rate_theta,
                                                     EMPTY if rate_psi is None else rate_psi)
        if which >= 0:
            return Health(False, f"non-finite values in {names[which]} at t = {solver.time(state):.6g}")
    else:
        for name in names:
            value = getattr(state, name)
            if value is not None and not np.all(np.isfinite(value)):
                return Health(False, f"non-finite values in {name} at t = {solver.time(state):.6g}")
        lo, hi = float(state.psi.min()), float(state.psi.max())
    center = state.center
    if not (math.isfinite(center.real) and math.isfinite(center.imag) and math.isfinite(state.shift)):
        return Health(False, f"non-finite position at t = {solver.time(state):.6g}")
    if abs(last_correction) > run.max_area_correction:
        return Health(False, f"one step changed the area by {last_correction:.3g} (relative; "
                             f"run.max_area_correction = {run.max_area_correction:g}) at "
                             f"t = {solver.time(state):.6g}: the time step is too large for this case")
    if lo < run.psi_min or hi > run.psi_max:
        return Health(False, f"psi left [{run.psi_min}, {run.psi_max}] (range [{lo:.4g}, {hi:.4g}]) at "
                             f"t = {solver.time(state):.6g}" + _overshoot_context(solver, state))
    if row is not None:
        for field, name, initial in zip(("theta", "psi"), ("tail_theta", "tail_psi"), solver.initial_tails):
            bound = max(run.max_spectral_tail, initial)
            if row[name] > bound:
                array = state.theta if field == "theta" else state.psi
                needed = resolution_needed(solver.sp.fft.rfft(array), solver.sp.N, 0.1 * run.max_spectral_tail)
                limit = (f"run.max_spectral_tail = {run.max_spectral_tail:g}" if bound == run.max_spectral_tail
                         else f"more than the initial shape's {initial:.2g}, itself above run.max_spectral_tail")
                num = solver.case.numerics
                largest = (" (numerics.N_max: N grew as far as it may)"
                           if num.adaptive_N and solver.sp.N >= num.N_max else "")
                return Health(False, f"the top third of the Fourier modes of {field} holds {row[name]:.2g} of its "
                                     f"variation ({limit}) at t = {row['t']:.6g}: N = {solver.sp.N}{largest} does "
                                     f"not resolve it; N = {needed} would (from the decay of its spectrum)"
                                     + _loose_step_hint(solver.case.numerics),
                              under_resolved=True)
        if abs(row["area_error"]) > run.max_area_error:
            return Health(False, f"relative area error {row['area_error']:.3g} exceeds "
                                 f"run.max_area_error = {run.max_area_error} at t = {row['t']:.6g}")
        if abs(row["length_error"]) > run.max_length_error:
            return Health(False, f"relative length error {row['length_error']:.3g} exceeds "
                                 f"run.max_length_error = {run.max_length_error} at t = {row['t']:.6g}")
    return HEALTHY


@dataclass(frozen=True)
class InclinationRecord:
    """theta at every sample time of a run made in memory (:func:`inclination_record`)."""

    t: np.ndarray
    theta: np.ndarray
    steps: int
    rejected: int
    state: State               # the state at t_end
    psi_range: tuple[float, float] = (np.nan, np.nan)   # min and max of psi over the samples


def inclination_record(case, start: State | None = None, engine: str | None = None) -> InclinationRecord:
    """Run ``case`` in memory to its t_end (from ``start``, default its initial state), keeping only
    theta at its sample times (no file, no checks); ``engine`` as Solver takes it.

    For benchmarks and measurements of the time stepping (bench/, analysis/error_rule.py); ``hpcves
    run`` (runner.py) records every series and watches the run's health.
    """
    from hpcves.run import schedule

    solver, clock = Solver(case, engine=engine), schedule.clock(case)
    state = solver.initial_state() if start is None else start
    times, theta, steps, rejected = [], [], 0, 0
    low, high = np.inf, -np.inf
    while True:
        rates = solver.rates(state)
        if clock.sample_due(state):
            times.append(state.t)
            theta.append(inclination(solver, state, rates))
            low, high = min(low, float(state.psi.min())), max(high, float(state.psi.max()))
        if clock.done(state):
            return InclinationRecord(np.array(times), np.array(theta), steps, rejected, state, (low, high))
        state, r = clock.take_step(solver, state, rates)
        steps, rejected = steps + 1, rejected + r
