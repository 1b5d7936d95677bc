"""The single-layer Stokes potential against exact results and against itself under refinement."""
import numpy as np
import pytest

from hpcves.model import geometry
from hpcves.numerics.quadrature import StokesSLP
from hpcves.numerics.spectral import Spectral


def circle(N, R):
    sp = Spectral(N, 2 * np.pi * R)
    phase = np.exp(2j * np.pi * sp.alpha)
    return sp, R * phase, 1j * phase          # positions, unit tangent (counter-clockwise)


@pytest.mark.parametrize("N", [16, 64])
def test_rotating_cylinder(N):
    # a unit tangential traction jump on a circle of radius R drives rigid rotation
    # with surface speed R/2 (interior rigid rotation, exterior u = Omega R^2 / r)
    R = 0.7
    sp, z, s = circle(N, R)
    slp = StokesSLP(N, sp.length)
    G = slp.assemble(z, s)
    assert np.allclose(slp.apply(G, s), 0.5 * R * s, atol=1e-14)


@pytest.mark.parametrize("N", [16, 64])
def test_uniform_normal_traction_drives_no_flow(N):
    # a uniform normal traction is a pressure jump: no velocity anywhere
    sp, z, s = circle(N, 0.4)
    slp = StokesSLP(N, sp.length)
    assert np.abs(slp.apply(slp.assemble(z, s), -1j * s)).max() < 1e-14


def test_operator_is_symmetric_and_nonnegative_on_an_ellipse():
    N = 64
    sp = Spectral(N, 2.6442)
    a, b = geometry.ellipse_for_excess_length(sp.length, 0.94)
    theta = geometry.close_curve(geometry.ellipse_equal_arclength(a, b, N)[1])
    z = sp.antiderivative_complex(np.exp(1j * theta), 0.0)
    slp = StokesSLP(N, sp.length)
    G = slp.matrix(slp.assemble(z, np.exp(1j * theta)))
    assert np.abs(G - G.T).max() < 1e-16
    assert np.linalg.eigvalsh(G).min() > -1e-12     # one zero mode: the normal (pressure) mode


def test_spectral_convergence_on_an_ellipse():
    """Velocity at fixed points of the ellipse from a smooth density, against N = 512."""
    def velocity(N):
        sp = Spectral(N, 2.6442)
        a, b = geometry.ellipse_for_excess_length(sp.length, 0.94)
        theta = geometry.close_curve(geometry.ellipse_equal_arclength(a, b, N)[1])
        s = np.exp(1j * theta)
        z = sp.antiderivative_complex(s, 0.0)
        f = (np.cos(2 * np.pi * sp.alpha) + 0.3j * np.sin(4 * np.pi * sp.alpha)) * s + 0.5 * (-1j * s)
        slp = StokesSLP(N, sp.length)
        u = slp.apply(slp.assemble(z, s), f)
        return u[:: N // 16]                       # the 16 nodes common to every N
    reference = velocity(512)
    errors = np.array([np.abs(velocity(N) - reference).max() for N in (16, 32, 64, 128, 256)])
    ratios = errors[:-1] / errors[1:]          # measured: 14, 77, 1.6e3, 7e5
    assert errors[0] > 1e-3                    # the test sees an error at N = 16...
    assert np.all(np.diff(ratios) > 0) and ratios[-1] > 1e4   # ...that falls faster than any power of N
    assert errors[-1] < 1e-13


def spectral_constraint_matrix(slp, blocks, tangent, sp):
    """B^T G B by its definition: -sum_ab diag(t_a) (D G_ab D) diag(t_b), D the spectral derivative."""
    D = np.array([sp.ds(e) for e in np.eye(sp.N)]).T          # D @ v = ds(v)
    T_xx, T_xy, T_yy = (D @ block @ D for block in slp.cartesian(blocks))
    c, s = tangent.real, tangent.imag
    return -(np.outer(c, c) * T_xx + np.outer(s, s) * T_yy + (np.outer(c, s) + np.outer(s, c)) * T_xy)


def constraint_matrix_error(excess_length, N):
    """max |closed form - D G D| / max |D G D| on an ellipse: (all, diagonal, off-diagonal)."""
    sp = Spectral(N, 2.6442)
    a, b = geometry.ellipse_for_excess_length(sp.length, excess_length)
    theta = geometry.close_curve(geometry.ellipse_equal_arclength(a, b, N)[1])
    tangent = np.exp(1j * theta)
    z = sp.antiderivative_complex(tangent, 0.3 - 0.2j)
    curvature = sp.ds(theta - 2 * np.pi * sp.alpha) + 2 * np.pi / sp.length
    slp = StokesSLP(N, sp.length)
    blocks = slp.assemble(z, tangent)
    A = slp.constraint_matrix(tangent, curvature)
    exact = spectral_constraint_matrix(slp, blocks, tangent, sp)
    scale = np.abs(exact).max()
    assert np.abs(A - A.T).max() < 1e-14 * scale
    error = np.abs(A - exact) / scale
    diagonal = np.diag(error).copy()
    np.fill_diagonal(error, 0.0)
    return max(diagonal.max(), error.max()), diagonal.max(), error.max()


def test_closed_form_constraint_matrix_on_a_circle_is_exact():
    # every kernel derivative of a circle is band-limited: nothing for the spectral derivative to miss
    assert constraint_matrix_error(0.0, 32)[0] < 1e-13


def test_closed_form_constraint_matrix_converges_spectrally_to_the_spectral_product():
    """Off the diagonal the kernels' analytic derivatives, on it their series limits
    (H^2 / 6 and (-H^2 + i H_s / 3) t^2): the difference from D G D is the error of
    spectrally differentiating the kernels. Measured on the Delta = 0.94 ellipse:
    3e-2, 5e-3, 1e-4, 9e-8, 1e-13 for N = 16 ... 256."""
    errors = np.array([constraint_matrix_error(0.94, N) for N in (16, 32, 64, 128, 256)])
    total, diagonal, off_diagonal = errors.T
    assert total[0] > 1e-2                                       # it is not exact...
    ratios = total[:-1] / total[1:]
    assert np.all(np.diff(ratios) > 0) and total[-1] < 1e-12     # ...but converges faster than any power
    assert np.all(off_diagonal < diagonal)
