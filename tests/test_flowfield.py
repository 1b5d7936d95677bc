"""The flow off the membrane (hpcves/model/flowfield.py): exact on a circle, the imposed shear far
away, and consistent with the solver's force and membrane velocity."""
import numpy as np
import pytest

from conftest import advance, make_solver
from hpcves.model import flowfield
from hpcves.model.forces import bending_force, tension_force
from hpcves.run import diagnostics

#: a force density on the circle |w| = R: sum of a_m e^{i m alpha} (complex = the vector)
MODES = {-9: 0.05j, -2: 0.3 + 0.1j, -1: 0.5j, 0: 0.7 - 0.2j, 1: -0.4 + 0.2j, 3: 0.25, 7: 0.1}
R = 0.5


def exact_single_layer(z, modes=MODES, radius=R):
    """(1/4 pi) int G(z - w) f(w) ds_w on |w| = radius, f = sum a_m e^{i m alpha}, in closed form.

    With r r^T / |r|^2 = I/2 + M(e^{2 i arg r})/2, M(c) v = c conj(v), each mode is a Laurent
    series: inside, -log|z - w| = -log R + Re sum (z e^{-i alpha}/R)^k / k and
    (z - w)/(conj z - conj w) = (z - w) (-e^{i alpha}/R) sum (conj z e^{i alpha}/R)^k; outside,
    the same in powers of R/z. Only the terms of zero net frequency survive the integral.
    """
    z = np.asarray(z, dtype=complex)
    zb, inside = np.conj(z), np.abs(z) < radius
    zo, zbo = np.where(inside, 1.0, z), np.where(inside, 1.0, zb)     # no division by 0 where unused
    total = np.zeros_like(z)
    for m, a in modes.items():
        if m == 0:
            log_in, log_out = -np.log(radius), -np.log(np.abs(zo))
        elif m > 0:
            log_in, log_out = (z / radius) ** m / (2 * m), (radius / zbo) ** m / (2 * m)
        else:
            log_in, log_out = (zb / radius) ** -m / (-2 * m), (radius / zo) ** -m / (-2 * m)
        rot_in = (-z * zb ** (m - 1) / radius ** m if m >= 1 else 0) + (zb ** (m - 2) / radius ** (m - 2)
                                                                        if m >= 2 else 0)
        rot_out = (zo * radius ** -m / zbo ** (1 - m) if m <= 0 else 0) - (radius ** (2 - m) / zbo ** (2 - m)
                                                                          if m <= 1 else 0)
        log_part = 2 * np.pi * radius * np.where(inside, log_in, log_out)
        rot_part = 2 * np.pi * radius * np.where(inside, rot_in, rot_out)
        total += (a * (log_part + (np.pi * radius if m == 0 else 0)) + 0.5 * np.conj(a) * rot_part) / (4 * np.pi)
    return total


def circle(N):
    alpha = np.arange(N) / N
    force = sum(a * np.exp(2j * np.pi * m * alpha) for m, a in MODES.items())
    return R * np.exp(2j * np.pi * alpha), force


def test_the_closed_form_is_the_single_layer():
    # checked against a fine trapezoid rule where that is exact (far from the circle)
    w, force = circle(20000)
    for x in (0.1 + 0.05j, -0.2j, 0.9 + 0.3j, 2.0 - 1.0j):
        r = x - w
        quadrature = np.sum((-np.log(np.abs(r)) * force + r * np.real(np.conj(r) * force) / np.abs(r) ** 2)
                            * (2 * np.pi * R / w.size)) / (4 * np.pi)
        assert abs(quadrature - exact_single_layer(x)) < 1e-14
    on = R * np.exp(2j * np.pi * np.arange(7) / 7)
    assert np.allclose(exact_single_layer(on * (1 - 1e-14)), exact_single_layer(on * (1 + 1e-14)), atol=1e-12)


@pytest.mark.parametrize("side", [1, -1])
def test_the_velocity_is_exact_on_a_circle_from_touching_to_far(side):
    N = 64
    w, force = circle(N)
    shear_rate = 3.0
    membrane = exact_single_layer(w) + shear_rate * w.imag
    h = 2 * np.pi * R / N
    scale = np.abs(membrane).max()
    for d in (1e-6, 1e-3, 0.01, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 4.9, 5.1, 10.0):   # in node spacings
        if side < 0 and d * h >= R:
            continue
        x = (R + side * d * h) * np.exp(1j * (np.linspace(0, 2 * np.pi, 37)[:-1] + 0.013))
        u = flowfield.velocity(x, w, force, membrane, shear_rate)
        error = np.abs(u - exact_single_layer(x) - shear_rate * x.imag).max() / scale
        assert error < 1e-8, (d, side, error)               # measured 3e-9 (the close zone) at most


def _snapshot_of_a_running_case(**physics):
    solver = make_solver(N=64, dt=1e-4, **physics)
    state = advance(solver, solver.initial_state(), 100)
    rates = solver.rates(state)
    return solver, rates, diagnostics.snapshot(solver, state, rates), state


def test_far_away_the_flow_is_the_imposed_shear_and_its_disturbance_a_stresslet():
    solver, _, snap, _ = _snapshot_of_a_running_case(psi_bar=0.3, shear_rate=80.0)
    z = snap["x"] + 1j * snap["y"]
    force = flowfield.traction(z, snap["psi"], snap["tension"], snap["curvature"], solver.case.physics)
    membrane = snap["velocity_x"] + 1j * snap["velocity_y"]
    disturbance = {}
    for r in (10.0, 100.0, 1000.0):
        x = r * np.exp(2j * np.pi * np.arange(16) / 16 + 0.1j)
        u = flowfield.velocity(x, z, force, membrane, 80.0)
        disturbance[r] = np.abs(u - 80.0 * x.imag).max()
        assert disturbance[r] < 1e-2 * 80.0 * r                     # small against the shear S r
    # zero total force and torque: the disturbance falls like 1/r, not like log r
    assert disturbance[1000.0] * 1000.0 == pytest.approx(disturbance[100.0] * 100.0, rel=0.01)
    assert disturbance[1000.0] / (80.0 * 1000.0) < 1e-6


def test_the_flow_off_the_membrane_meets_the_solvers_membrane_velocity():
    solver, rates, snap, state = _snapshot_of_a_running_case(psi_bar=0.3, shear_rate=80.0)
    sp, shape, physics = solver.sp, rates.shape, solver.case.physics
    z = snap["x"] + 1j * snap["y"]
    force = flowfield.traction(z, snap["psi"], snap["tension"], snap["curvature"], physics)
    direct = bending_force(shape.curvature, state.psi, rates.psi_s, shape.tangent, physics, sp) \
        + tension_force(rates.flow.tension_eff, shape.tangent, sp)
    # the snapshot's tangent is dz/ds of its nodes, the solver's e^{i theta}: they differ by what
    # N = 64 leaves unresolved of the shape (1e-6 of the force here, 3e-8 at N = 128, Delta = 2.3)
    assert np.abs(force - direct).max() < 1e-5 * np.abs(direct).max()
    # the quadrature alone (a NaN membrane velocity: never used there), extrapolated to the membrane
    h, normal = sp.length / sp.N, shape.normal
    distances = np.linspace(0.16, 0.6, 6) * h          # the near zone (from 5 h / 32 on)
    unknown = np.full(sp.N, np.nan + 0j)
    membrane = rates.flow.velocity
    for side in (1, -1):
        values = np.array([flowfield.velocity(z + side * d * normal, z, force, unknown, 80.0) for d in distances])
        assert np.all(np.isfinite(values))
        at_membrane = np.linalg.solve(np.vander(distances, distances.size), values)[-1]
        # measured 1.3e-6 outside, 1.3e-7 inside: the extrapolation's error and the force's above
        assert np.abs(at_membrane - membrane).max() < 1e-5 * np.abs(membrane).max(), side


@pytest.mark.parametrize("viscosity_ratio", [0.2, 5.0])
def test_the_double_layer_of_a_rigid_motion_and_the_winding_number(viscosity_ratio):
    """Off a closed curve the double layer of a rigid motion v is -(1 - lambda) v inside and 0 outside
    (the identity its jump comes from), by the plain rule far away and the upsampled one near; the
    winding number is 1 inside and 0 outside."""
    N = 64
    alpha = np.arange(N) / N
    z = 0.6 * np.cos(2 * np.pi * alpha) + 0.35j * np.sin(2 * np.pi * alpha) + 0.08 * np.exp(6j * np.pi * alpha)
    rigid = 0.3 - 0.2j + 1.7j * (z - 0.05)                              # a translation and a rotation
    coarse = flowfield._Curve(z, np.zeros(N, dtype=complex), rigid, viscosity_ratio)
    fine = coarse.upsampled(flowfield.UPSAMPLE * N)
    h = coarse.length / N
    inner = np.array([0.0, 0.2 + 0.05j, -0.3])
    outer = np.array([2.0, 1.5j, -1.2 - 0.8j])
    assert list(coarse.winding(inner)) == [1, 1, 1] and list(coarse.winding(outer)) == [0, 0, 0]
    expected = -(1.0 - viscosity_ratio) * (0.3 - 0.2j + 1.7j * (inner - 0.05))
    assert np.abs(coarse.double_layer(inner) - expected).max() < 1e-10
    assert np.abs(coarse.double_layer(outer)).max() < 1e-10
    normal = -1j * coarse.dz / np.abs(coarse.dz)
    for d in (0.5 * h, 2.0 * h):                                      # the near zone, both sides
        inside = z[::8] - d * normal[::8]
        outside = z[::8] + d * normal[::8]
        expected = -(1.0 - viscosity_ratio) * (0.3 - 0.2j + 1.7j * (inside - 0.05))
        assert np.abs(fine.double_layer(inside) - expected).max() < 1e-9
        assert np.abs(fine.double_layer(outside)).max() < 1e-9
