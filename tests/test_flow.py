import numpy as np

from conftest import advance, make_solver


def test_tension_makes_the_flow_inextensible_and_the_system_is_spd():
    solver = make_solver(N=64, dt=1e-3, shear_rate=80.0, psi_bar=0.3, excess_length=0.94)
    state = advance(solver, solver.initial_state(), 20)
    rates = solver.rates(state)
    shape, flow = rates.shape, rates.flow
    stretching = flow.stretching(shape.tangent, solver.sp)
    velocity_gradient = np.abs(solver.sp.ds_complex(flow.velocity)).max()
    assert np.abs(stretching).max() < 1e-10 * velocity_gradient
    blocks = solver.flow.slp.assemble(shape.z, shape.tangent)
    A = solver.flow.constraint_matrix(blocks, shape.tangent).copy()
    assert np.abs(A - A.T).max() < 1e-10 * np.abs(A).max()
    assert np.linalg.eigvalsh(0.5 * (A + A.T)).min() > 0


def test_flow_is_area_preserving():
    solver = make_solver(N=64, dt=1e-3, shear_rate=10.0, psi_bar=0.3)
    state = solver.initial_state()
    rates = solver.rates(state)
    normal_velocity = np.real(np.conj(rates.shape.normal) * rates.flow.velocity)
    assert abs(normal_velocity.mean()) < 1e-14 * np.abs(rates.flow.velocity).max()
