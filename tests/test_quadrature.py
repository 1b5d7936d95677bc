"""The single-layer Stokes potential against exact results and against itself under refinement."""
import numpy as np
import pytest

from hpcves import geometry
from hpcves.quadrature import StokesSLP
from hpcves.spectral import Spectral


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
