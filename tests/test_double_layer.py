"""The Stokes double layer of a viscosity contrast (numerics/double_layer.py): its identities on the
curve, its diagonal limit, its spectral convergence, and an independent quadrature."""
import numpy as np
import pytest
from scipy.integrate import quad

from hpcves.numerics.double_layer import apply_double_layer, double_layer_matrix

TWO_PI = 2.0 * np.pi


def curve(N: int, shape: str = "ellipse"):
    """(z, tangent, curvature, weights) at alpha_j = j / N of a smooth closed curve, counter-clockwise
    and not parametrised by arclength (the operator must take any nodes with their weights)."""
    alpha = np.arange(N) / N
    if shape == "ellipse":
        a, b = 1.0, 0.45
        z = a * np.cos(TWO_PI * alpha) + 1j * b * np.sin(TWO_PI * alpha)
        dz = TWO_PI * (-a * np.sin(TWO_PI * alpha) + 1j * b * np.cos(TWO_PI * alpha))
        ddz = -TWO_PI ** 2 * z
    else:                    # a lopsided, non-convex curve: r(phi) = 1 + 0.3 cos 3 phi + 0.15 sin 2 phi
        phi = TWO_PI * alpha
        r = 1 + 0.3 * np.cos(3 * phi) + 0.15 * np.sin(2 * phi)
        dr = TWO_PI * (-0.9 * np.sin(3 * phi) + 0.3 * np.cos(2 * phi))
        ddr = TWO_PI ** 2 * (-2.7 * np.cos(3 * phi) - 0.6 * np.sin(2 * phi))
        e = np.exp(1j * phi)
        z = r * e
        dz = (dr + 1j * TWO_PI * r) * e
        ddz = (ddr + 2j * TWO_PI * dr - TWO_PI ** 2 * r) * e
    speed = np.abs(dz)
    curvature = (dz.real * ddz.imag - dz.imag * ddz.real) / speed ** 3
    return z, dz / speed, curvature, speed / N


@pytest.mark.parametrize("shape", ["ellipse", "lopsided"])
@pytest.mark.parametrize("viscosity_ratio", [0.1, 5.0])
def test_a_rigid_motion_comes_back_times_minus_half_of_one_minus_lambda(shape, viscosity_ratio):
    """D[u] = -(1 - lambda)/2 u on the curve for a translation and a rotation (about a point off the
    centre): the constants and the sign of the kernel, and its diagonal limit (an O(h) error without)."""
    z, t, H, w = curve(128, shape)
    D = double_layer_matrix(z, t, H, w, viscosity_ratio)
    half = -(1.0 - viscosity_ratio) / 2.0
    for u in (np.full(z.size, 0.3 - 0.7j), 1j * 0.8 * (z - (0.2 + 0.1j))):
        assert np.abs(apply_double_layer(D, u) - half * u).max() < 1e-11 * np.abs(u).max()
    without_limit = D.copy()
    np.fill_diagonal(without_limit, 0.0)
    u = np.full(z.size, 1.0 + 0j)
    assert np.abs(apply_double_layer(without_limit, u) - half * u).max() > 1e-4   # the limit matters


def test_equal_viscosities_have_no_double_layer():
    z, t, H, w = curve(32)
    assert not double_layer_matrix(z, t, H, w, 1.0).any()


@pytest.mark.parametrize("shape, sizes", [("ellipse", (8, 16, 32)), ("lopsided", (16, 32, 64, 128))])
def test_the_operator_converges_spectrally_on_a_smooth_field(shape, sizes):
    """D of a smooth, non-rigid velocity at the nodes shared by each N and N = 512: the error falls by
    a factor that itself grows as N doubles -- faster than any power of 1/N -- down to round-off
    (measured: ellipse 2.7e-2, 2.7e-5, 1.1e-11 at N = 8, 16, 32; lopsided 5.4e-3, 8.3e-5, 1.3e-8,
    3.2e-14 at N = 16 ... 128)."""
    def velocity(z):
        return z.real ** 2 - 0.5j * z.imag * z.real + 0.3j * z.imag ** 3

    z, t, H, w = curve(512, shape)
    reference = apply_double_layer(double_layer_matrix(z, t, H, w, 0.2), velocity(z))
    errors = []
    for N in sizes:
        zN, tN, HN, wN = curve(N, shape)
        value = apply_double_layer(double_layer_matrix(zN, tN, HN, wN, 0.2), velocity(zN))
        errors.append(np.abs(value - reference[:: 512 // N]).max() / np.abs(reference).max())
    factors = [earlier / later for earlier, later in zip(errors, errors[1:])]
    assert factors[0] > 50 and all(later > earlier for earlier, later in zip(factors, factors[1:])), errors
    assert errors[-1] < 1e-10, errors


def test_a_node_agrees_with_adaptive_quadrature_of_the_kernel():
    """The operator at one node against scipy's adaptive quadrature of the kernel written out
    (x, y, n as real vectors) on the exact ellipse: the kernel and its constants, independently."""
    viscosity_ratio, a, b, alpha0 = 4.0, 1.0, 0.45, 0.13

    def point(alpha):
        return np.array([a * np.cos(TWO_PI * alpha), b * np.sin(TWO_PI * alpha)])

    def derivative(alpha):
        return TWO_PI * np.array([-a * np.sin(TWO_PI * alpha), b * np.cos(TWO_PI * alpha)])

    def velocity(p):
        return np.array([p[0] ** 2, 0.5 * p[0] * p[1] - 0.2])

    x = point(alpha0)

    def integrand(alpha, i):
        y, dy = point(alpha), derivative(alpha)
        speed = np.hypot(*dy)
        n = np.array([dy[1], -dy[0]]) / speed             # outward on a counter-clockwise curve
        r = x - y
        rr = r @ r
        if rr < 1e-24:
            return 0.0                                     # a removable point (measure zero)
        return (1 - viscosity_ratio) / np.pi * (r @ n) * r[i] * (r @ velocity(y)) / rr ** 2 * speed

    expected = [quad(integrand, alpha0, alpha0 + 1.0, args=(i,), epsabs=1e-13, epsrel=1e-13, limit=200)[0]
                for i in (0, 1)]
    N = 200
    alpha = np.arange(N) / N
    z0 = complex(*point(alpha0))
    shifted = curve_at(alpha + alpha0, a, b)              # nodes starting at alpha0
    D = double_layer_matrix(*shifted, viscosity_ratio)
    u = velocity(np.array([shifted[0].real, shifted[0].imag]))
    value = apply_double_layer(D, u[0] + 1j * u[1])[0]
    assert abs(shifted[0][0] - z0) < 1e-15
    assert value.real == pytest.approx(expected[0], abs=1e-11)
    assert value.imag == pytest.approx(expected[1], abs=1e-11)


def curve_at(alpha, a, b):
    """The ellipse's (z, tangent, curvature, weights) at the nodes ``alpha`` (equally spaced)."""
    z = a * np.cos(TWO_PI * alpha) + 1j * b * np.sin(TWO_PI * alpha)
    dz = TWO_PI * (-a * np.sin(TWO_PI * alpha) + 1j * b * np.cos(TWO_PI * alpha))
    ddz = -TWO_PI ** 2 * z
    speed = np.abs(dz)
    return z, dz / speed, (dz.real * ddz.imag - dz.imag * ddz.real) / speed ** 3, speed / alpha.size
