"""numerics/krylov.py: right-preconditioned GMRES against a dense solve."""
import numpy as np
import pytest

from hpcves.numerics.krylov import gmres


def _system(rng, n=40):
    """A nonsymmetric K = I + (a compact-like part): the shape of the contrast's preconditioned system."""
    K = np.eye(n) + rng.standard_normal((n, n)) * (0.5 ** np.arange(n))[None, :]
    return K, rng.standard_normal(n)


def test_it_meets_the_dense_solve_with_and_without_a_preconditioner(rng):
    K, b = _system(rng)
    exact = np.linalg.solve(K, b)
    for M in (np.eye(b.size), np.linalg.inv(K + 0.1 * rng.standard_normal(K.shape))):
        x, residual, iterations = gmres(lambda v: (M @ v, K @ (M @ v)), b, 1e-12, b.size)
        assert residual <= 1e-12
        assert np.linalg.norm(b - K @ x) <= 2e-12 * np.linalg.norm(b)       # the residual it reports is true
        assert np.abs(x - exact).max() < 1e-10 * np.abs(exact).max()
        assert 1 <= iterations < b.size


def test_a_good_preconditioner_takes_fewer_iterations(rng):
    K, b = _system(rng)
    plain = gmres(lambda v: (v, K @ v), b, 1e-10, b.size)[2]
    Minv = np.linalg.inv(K + 1e-3 * rng.standard_normal(K.shape))
    assert gmres(lambda v: (Minv @ v, K @ (Minv @ v)), b, 1e-10, b.size)[2] < plain


def test_it_reports_what_it_could_not_reach_and_solves_zero_for_free(rng):
    K, b = _system(rng)
    x, residual, iterations = gmres(lambda v: (v, K @ v), b, 1e-14, 2)
    assert iterations == 2 and residual > 1e-14
    assert residual == pytest.approx(np.linalg.norm(b - K @ x) / np.linalg.norm(b), rel=1e-8)
    x, residual, iterations = gmres(lambda v: (v, K @ v), np.zeros(b.size), 1e-12, 5)
    assert iterations == 0 and residual == 0.0 and not x.any()


def test_an_invariant_space_ends_it_exactly():
    """b an eigenvector: one iteration, H[1, 0] = 0, the exact answer."""
    K = np.diag([2.0, 3.0, 4.0])
    x, residual, iterations = gmres(lambda v: (v, K @ v), np.array([1.0, 0.0, 0.0]), 1e-12, 3)
    assert iterations == 1 and residual == 0.0
    assert np.allclose(x, [0.5, 0.0, 0.0], rtol=0, atol=1e-15)
