"""A viscosity contrast lambda = eta_in / eta_out (physics.viscosity_ratio; issue #42): the parameter,
the membrane's flow with the double layer, and what it does to a vesicle."""
import dataclasses

import numpy as np
import pytest

from conftest import advance, make_solver
from hpcves.config import case_from_toml
from hpcves.model.flow import MembraneFlow, TensionSolveError, rigid_motions
from hpcves.model.forces import bending_force, tension_force
from hpcves.model.params import Case, ConfigError, Numerics, Physics, RunControl
from hpcves.numerics.double_layer import apply_double_layer, double_layer_matrix
from hpcves.solver.timestepping import Solver


def test_the_parameter_defaults_to_equal_viscosities_and_old_files_keep_their_fingerprint():
    assert Physics().viscosity_ratio == 1.0
    assert "viscosity_ratio" not in Case().significant()["physics"]          # files from before it
    assert Case(Physics(viscosity_ratio=3.0)).significant()["physics"]["viscosity_ratio"] == 3.0
    assert case_from_toml("[physics]\nviscosity_ratio = 0.5\n").physics.viscosity_ratio == 0.5
    with pytest.raises(ConfigError, match="viscosity_ratio"):
        case_from_toml("[physics]\nviscosity_ratio = 0.0\n")


def test_a_contrast_runs_on_both_engines_and_they_agree():
    """The compiled engine runs the numpy path's GMRES (solver/compiled.py): the same iteration, so the
    same iterations, and the two differ by round-off, as at equal viscosities."""
    thetas = {}
    for engine in ("numpy", "compiled"):
        solver = Solver(Case(Physics(psi_bar=0.3, shear_rate=20.0, viscosity_ratio=4.0), Numerics(N=64, dt=5e-4),
                             RunControl(t_end=1.0)), engine=engine)
        assert solver.engine == engine
        thetas[engine] = advance(solver, solver.initial_state(), 60).theta
    assert Solver(Case(Physics(viscosity_ratio=4.0))).engine == "compiled"
    assert np.abs(thetas["numpy"] - thetas["compiled"]).max() < 1e-12


def _running(viscosity_ratio, steps=40, **physics):
    solver = make_solver(N=64, dt=1e-4, shear_rate=5.0, psi_bar=0.3, viscosity_ratio=viscosity_ratio, **physics)
    state = advance(solver, solver.initial_state(), steps)
    return solver, state, solver.rates(state)


@pytest.mark.parametrize("viscosity_ratio", [0.1, 4.0])
def test_the_velocity_solves_the_second_kind_equation_and_is_inextensible(viscosity_ratio):
    """((1 + lambda)/2) u - D[u] = u_inf + S[f_b + d(Lambda~ s)/ds] at the nodes, s . du/ds = 0."""
    solver, state, rates = _running(viscosity_ratio)
    shape, flow, sp = rates.shape, rates.flow, solver.sp
    D = double_layer_matrix(shape.z, shape.tangent, shape.curvature, sp.length / sp.N, viscosity_ratio)
    slp = solver.flow.slp
    blocks = slp.assemble(shape.z, shape.tangent)
    driving = slp.apply(blocks, bending_force(shape.curvature, state.psi, rates.psi_s, shape.tangent,
                                              solver.case.physics, sp)) + solver.case.physics.shear_rate * shape.z.imag
    right = driving + slp.apply(blocks, tension_force(flow.tension_eff, shape.tangent, sp))
    u = flow.velocity
    left = 0.5 * (1.0 + viscosity_ratio) * u - apply_double_layer(D, u)
    stretching = (np.conj(shape.tangent) * sp.ds_complex(u)).real
    residual = np.sqrt(np.sum(np.abs(left - right) ** 2) + np.sum(stretching ** 2))
    # GMRES stops at |b - K x| <= GMRES_TOLERANCE |b|, b = (u_inf + G f_b, 0)
    size = np.sqrt(np.sum(np.abs(driving) ** 2))
    assert residual <= 2 * MembraneFlow.GMRES_TOLERANCE * size
    assert residual > 0


def _dense_flow(solver, state, rates):
    """u and Lambda~ of the contrast's system (flow.MembraneFlow._solve_with_contrast) by one dense LU
    solve of the whole 3N x 3N system: the reference GMRES must meet."""
    from hpcves.model.forces import bending_force
    shape, sp, phys, slp, N = rates.shape, solver.sp, solver.case.physics, solver.flow.slp, solver.sp.N
    c = 0.5 * (1.0 + phys.viscosity_ratio)
    blocks = slp.assemble(shape.z, shape.tangent)
    G = slp.matrix(blocks)
    u0 = slp.apply(blocks, bending_force(shape.curvature, state.psi, rates.psi_s, shape.tangent, phys, sp)) \
        + phys.shear_rate * shape.z.imag
    derivative = np.column_stack([np.array(sp.ds(e)) for e in np.eye(N)])
    B = derivative * shape.tangent[None, :]                        # column j: d(e_j s)/ds
    K = np.zeros((3 * N, 3 * N))
    K[:2 * N, :2 * N] = c * np.eye(2 * N) - double_layer_matrix(shape.z, shape.tangent, shape.curvature,
                                                                 sp.length / N, phys.viscosity_ratio)
    K[:2 * N, 2 * N:] = -G @ np.concatenate([B.real, B.imag])
    K[2 * N:, :N] = shape.tangent.real[:, None] * derivative
    K[2 * N:, N:2 * N] = shape.tangent.imag[:, None] * derivative
    x = np.linalg.solve(K, np.concatenate([u0.real, u0.imag, np.zeros(N)]))
    return x[:N] + 1j * x[N:2 * N], x[2 * N:]


@pytest.mark.parametrize("physics", [dict(psi_bar=0.5, excess_length=0.94),
                                     dict(psi_bar=0.5, excess_length=2.3, initial_shape="smoothed")])
@pytest.mark.parametrize("viscosity_ratio", [0.1, 10.0, 100.0])
def test_gmres_meets_the_dense_solve(physics, viscosity_ratio):
    """GMRES stopped at a relative residual of 1e-10 (MembraneFlow.GMRES_TOLERANCE) against a dense
    solve of the same 3N x 3N system: measured 3e-12 to 1.7e-10 relative in u, 4e-12 to 3e-11 in
    Lambda~."""
    solver = make_solver(N=128, dt=1e-4, shear_rate=5.0, viscosity_ratio=viscosity_ratio, **physics)
    state = advance(solver, solver.initial_state(), 10)
    rates = solver.rates(state)
    velocity, tension = _dense_flow(solver, state, rates)
    scale = np.abs(velocity).max()
    assert np.abs(rates.flow.velocity - velocity).max() < 2e-9 * scale
    assert np.abs(rates.flow.tension_eff - tension).max() < 2e-9 * np.abs(tension).max()


def test_a_solve_that_does_not_converge_stops_the_run(monkeypatch):
    solver, state, _ = _running(4.0, steps=2)
    monkeypatch.setattr(MembraneFlow, "MAX_ITERATIONS", 1)
    with pytest.raises(TensionSolveError, match="GMRES"):
        Solver(solver.case, engine="numpy").rates(state)


def test_the_rigid_motions_are_orthonormal_and_the_double_layer_gives_them_back_scaled():
    """The deflation of the preconditioner rests on D[rigid] = -(1 - lambda)/2 rigid (to the trapezoid
    rule's error: measured 9e-10 at N = 64)."""
    solver, state, rates = _running(4.0, steps=2)
    shape, sp = rates.shape, solver.sp
    Q = rigid_motions(shape.z)
    assert np.allclose(Q.T @ Q, np.eye(3), atol=1e-14)
    D = double_layer_matrix(shape.z, shape.tangent, shape.curvature, sp.length / sp.N, 4.0)
    assert np.abs(D @ Q - (-(1.0 - 4.0) / 2.0) * Q).max() < 1e-8


def test_near_equal_viscosities_gmres_meets_the_cholesky_one():
    """lambda = 1 + 1e-9 takes the contrast's GMRES, lambda = 1 the Cholesky of B^T G B with its
    refinement: two solves of the same system that agree to the contrast's O(1e-9) effect."""
    solver, state, rates = _running(1.0)
    near = Solver(dataclasses.replace(solver.case, physics=dataclasses.replace(solver.case.physics,
                                                                                viscosity_ratio=1.0 + 1e-9)))
    other = near.rates(state)
    scale = np.abs(rates.flow.velocity).max()
    assert np.abs(other.flow.velocity - rates.flow.velocity).max() < 1e-8 * scale
    assert np.abs(other.flow.tension_eff - rates.flow.tension_eff).max() < 1e-8 * np.abs(rates.flow.tension_eff).max()
    assert np.abs(other.flow.velocity - rates.flow.velocity).max() > 0        # it did take the other path


def test_a_more_viscous_inside_tank_treads_slower():
    """The same shape and phase in the same shear: the membrane's mean tangential speed falls as the
    inside grows more viscous (Keller & Skalak 1982), and the inside flow no longer matches the outside."""
    speeds = []
    _, state, _ = _running(1.0)
    for viscosity_ratio in (0.25, 1.0, 4.0, 16.0):
        solver = make_solver(N=64, dt=1e-4, shear_rate=5.0, psi_bar=0.3, viscosity_ratio=viscosity_ratio)
        speeds.append(abs(solver.rates(state).mean_tangential_velocity))
    assert speeds[0] > speeds[1] > speeds[2] > speeds[3] > 0, speeds


@pytest.mark.parametrize("viscosity_ratio", [0.1, 10.0])
def test_energy_never_increases_at_S0(viscosity_ratio):
    """No flow imposed: bending and line energy only fall while the phases separate and the shape
    relaxes, whatever the viscosities (the dissipation changes, the gradient flow stays one)."""
    solver = make_solver(N=64, dt=2e-5, shear_rate=0.0, psi_bar=0.5, viscosity_ratio=viscosity_ratio)
    state = solver.initial_state()
    energy = [sum(solver.energies(state))]
    for _ in range(600):                                              # t = 0.012: the spinodal stage
        state, _, _ = solver.step(state)
        energy.append(sum(solver.energies(state)))
    energy = np.array(energy)
    assert np.all(np.diff(energy) <= 1e-12 * energy[:-1]), np.diff(energy).max()
    assert energy[-1] < 0.9 * energy[0]


@pytest.mark.parametrize("viscosity_ratio", [0.2, 5.0])
def test_the_flow_off_the_membrane_meets_its_velocity_from_both_sides(viscosity_ratio):
    """Off the membrane u = u_inf + SLP[f] + DLP[u] outside and lambda u = the same inside
    (flowfield.py). The near zone's values (the upsampled rule, D ... 6 D off the membrane, not
    told the membrane's velocity) extrapolated to the membrane meet its velocity on each side:
    measured 3e-6 ... 1.3e-5 of max |u|; a double layer's jump off by its (1 - lambda)/2 u, or the
    inside not divided by lambda, would miss by O(1)."""
    from hpcves.model import flowfield

    solver, state, rates = _running(viscosity_ratio, steps=20)
    shape, sp = rates.shape, solver.sp
    force = bending_force(shape.curvature, state.psi, rates.psi_s, shape.tangent, solver.case.physics, sp) \
        + tension_force(rates.flow.tension_eff, shape.tangent, sp)
    u, z, normal = rates.flow.velocity, shape.z, -1j * shape.tangent
    S = solver.case.physics.shear_rate
    fine = flowfield._Curve(z, force, u, viscosity_ratio).upsampled(flowfield.UPSAMPLE * sp.N)
    steps = np.arange(1, flowfield.CLOSE_POINTS + 1) * flowfield.NEAR * (sp.length / sp.N) / flowfield.UPSAMPLE
    to_membrane = flowfield._lagrange_weights(steps, np.zeros(z.size))
    for side in (1.0, -1.0):
        probes = z[:, None] + side * normal[:, None] * steps[None, :]
        values = fine.disturbance(probes.ravel(), np.full(probes.size, side < 0), S).reshape(probes.shape)
        extrapolated = np.sum(to_membrane * values, axis=1) + S * z.imag
        assert np.abs(extrapolated - u).max() < 1e-4 * np.abs(u).max()
    # and the public function, through all three zones, is continuous onto the membrane from both sides
    h = sp.length / sp.N
    for side in (1.0, -1.0):
        near = flowfield.velocity(z + side * 1e-6 * h * normal, z, force, u, S, viscosity_ratio)
        assert np.abs(near - u).max() < 1e-5 * np.abs(u).max()


def test_streamlines_are_drawn_around_a_vesicle_with_a_contrast():
    from hpcves.model.flowfield import around_snapshot
    from hpcves.run import diagnostics

    solver, state, rates = _running(2.0, steps=2)
    snapshot = diagnostics.snapshot(solver, state, rates)
    z = np.asarray(snapshot["x"]) + 1j * np.asarray(snapshot["y"])
    centre = z.mean()
    S = solver.case.physics.shear_rate
    far, middle = around_snapshot(snapshot, solver.case.physics, np.array([centre + 20j, centre]))
    assert abs(far - S * (centre.imag + 20.0)) < 5e-3 * S * 20.0        # the imposed shear, a stresslet off
    assert np.isfinite(middle) and abs(middle) < np.abs(rates.flow.velocity).max()


@pytest.mark.parametrize("viscosity_ratio", [0.1, 10.0])
def test_second_order_in_time(viscosity_ratio):
    """Positions after t = 0.05 (homogeneous, Delta = 0.94, S = 5, N = 32) against dt = 3.125e-5.
    Measured: orders 1.99, 2.04 (lambda = 0.1) and 1.85, 1.98 (lambda = 10: its errors are smaller
    and reach the asymptotic order later; 1.60, 1.67, 1.76, 1.86 from dt = 2e-3 at lambda = 4)."""
    def positions(dt):
        solver = make_solver(N=32, dt=dt, shear_rate=5.0, psi_bar=0.0, excess_length=0.94,
                             viscosity_ratio=viscosity_ratio)
        return solver.shape(advance(solver, solver.initial_state(), round(0.05 / dt))).z

    reference = positions(3.125e-5)
    errors = np.array([np.abs(positions(dt) - reference).max() for dt in (5e-4, 2.5e-4, 1.25e-4)])
    orders = np.log2(errors[:-1] / errors[1:])
    assert np.all((orders >= 1.75) & (orders <= 2.25)), orders
    assert orders[-1] == pytest.approx(2.0, abs=0.15), orders


def test_an_adaptive_run_with_a_contrast_resumed_from_its_checkpoints_is_bitwise_identical(tmp_path):
    from hpcves.run.store import FINISHED, INTERRUPTED
    from jobs import SHORT, resume_in_process, run_in_process, same_case_files

    text = SHORT.replace("dt = 1e-3", "rtol = 1e-2").replace("psi_bar = 0.3", "psi_bar = 0.3\nviscosity_ratio = 5.0")
    case = case_from_toml(text.format(t_end=0.2, checkpoint=0.04))
    assert case.physics.viscosity_ratio == 5.0 and case.numerics.adaptive
    assert run_in_process(case, tmp_path / "a.h5").status == FINISHED
    assert run_in_process(case, tmp_path / "b.h5", max_steps=61).status == INTERRUPTED
    assert resume_in_process(tmp_path / "b.h5", stops=(40, 3, None)).status == FINISHED
    same_case_files(tmp_path / "a.h5", tmp_path / "b.h5", checkpoints=True)


STUDY = """
[campaign]
name = "contrast"
output = "{output}"
t_end = 0.2
[physics]
shear_rate = 20.0
[numerics]
N = 32
dt = 1e-3
[run]
max_spectral_tail = 1.0          # N = 32 on purpose (fast)
sample_interval = 0.01
snapshot_interval = 0.1
checkpoint_interval = 0.1
[sweep]
viscosity_ratio = [0.5, 2.0]
psi_bar = [0.3]
"""


def test_a_campaign_sweeps_the_viscosity_ratio_and_its_table_has_the_column(tmp_path):
    """[sweep] viscosity_ratio: each case runs with its lambda, and the analysis table has its column."""
    from hpcves.campaign.driver import run_campaign
    from hpcves.campaign.study import study_from_toml
    from hpcves.reports.analyze import analyze

    output = tmp_path / "c.h5"
    study = study_from_toml(STUDY.format(output=output))
    assert [c.case.physics.viscosity_ratio for c in study.cases] == [0.5, 2.0]
    assert run_campaign(study, output).exit_status == 0
    report = analyze(output, tmp_path / "a", case_figures=False)
    rows = sorted(report.rows, key=lambda r: r["viscosity_ratio"])
    assert [r["viscosity_ratio"] for r in rows] == [0.5, 2.0] and {r["status"] for r in rows} == {"finished"}
    header = (tmp_path / "a" / "regimes.csv").read_text().splitlines()[0].split(",")
    assert "viscosity_ratio" in header


def test_a_case_written_before_the_parameter_reads_as_equal_viscosities(tmp_path):
    """Files from before physics.viscosity_ratio hold no such attribute: their rows say 1."""
    import h5py

    from hpcves.run import verdict
    from hpcves.run.store import CaseStore
    from jobs import SHORT, run_in_process

    run_in_process(case_from_toml(SHORT.format(t_end=0.01, checkpoint=0.01)), tmp_path / "old.h5")
    with h5py.File(tmp_path / "old.h5", "r+") as f:
        del f.attrs["physics.viscosity_ratio"]                 # as a file written before it
    with h5py.File(tmp_path / "old.h5", "r") as f:
        data = verdict.case_data(CaseStore.open(f), "old")
    assert data.parameters["viscosity_ratio"] == 1.0 and data.parameters["shear_rate"] == 80.0


@pytest.mark.parametrize("orientation", [0.0, np.pi / 4, np.pi / 2, 2.0])
def test_a_very_viscous_inside_turns_the_ellipse_as_a_rigid_body_at_jefferys_rate(orientation):
    """lambda -> infinity: the inside cannot flow, the membrane moves rigidly, and the ellipse turns at
    Jeffery's rate -S (r^2 sin^2 phi + cos^2 phi) / (r^2 + 1) (Jeffery 1922; r the axis ratio, phi the
    long axis's angle to the flow), translating not at all. Measured at lambda = 1e4 (Delta = 1.45087,
    reduced area 0.66, N = 128): 6e-5 to 8e-5 relative, the O(1/lambda) of a finite contrast; at
    lambda = 1e6 the discretisation error of D on rigid motions, amplified by lambda, makes it 6e-3."""
    from scipy.optimize import brentq

    from hpcves.model.geometry import excess_length_of_ellipse

    delta, S = 1.45087, 10.0
    solver = make_solver(N=128, dt=1e-4, shear_rate=S, psi_bar=0.0, excess_length=delta, viscosity_ratio=1e4)
    start = solver.initial_state()
    rates = solver.rates(dataclasses.replace(start, theta=start.theta + orientation))   # turned by phi
    z, u = rates.shape.z, rates.flow.velocity
    arm = z - z.mean()
    rigid = np.vstack([np.column_stack([np.ones_like(arm.real), np.zeros_like(arm.real), -arm.imag]),
                       np.column_stack([np.zeros_like(arm.real), np.ones_like(arm.real), arm.real])])
    (Ux, Uy, omega), *_ = np.linalg.lstsq(rigid, np.concatenate([u.real, u.imag]), rcond=None)
    r = 1.0 / brentq(lambda q: excess_length_of_ellipse(q) - delta, 0.05, 0.9999)
    jeffery = -S * (r**2 * np.sin(orientation) ** 2 + np.cos(orientation) ** 2) / (r**2 + 1.0)
    assert abs(omega / jeffery - 1.0) < 3e-4
    assert abs(Ux) + abs(Uy) < 1e-9 * S
    # what is not rigid is O(S L / lambda): the bending force's flow, divided by the inside's viscosity
    assert np.abs(rigid @ [Ux, Uy, omega] - np.concatenate([u.real, u.imag])).max() < 2e-3 * S * np.abs(arm).max()
