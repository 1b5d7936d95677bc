"""Every term of the membrane force against a finite-difference derivative of the discrete energy.

dE = -int f . phi ds for smooth normal and tangential displacements phi of the
material points (psi carried along). SPEC section 1 warns that the published
tangential term has the wrong sign for mu psi_s; the last test shows that the
published sign does fail this check.
"""
import numpy as np
import pytest

from hpcves.model import geometry, phasefield
from hpcves.model.forces import bending_force, energy_terms, tension_force
from hpcves.model.params import Physics
from hpcves.numerics.spectral import Spectral

N, L = 64, 2.6442


def make_membrane(N):
    sp = Spectral(N, L)
    a, b = geometry.ellipse_for_excess_length(L, 0.194)
    theta = geometry.close_curve(geometry.ellipse_equal_arclength(a, b, N)[1])
    tangent = np.exp(1j * theta)
    z = sp.antiderivative_complex(tangent, 0.1 + 0.2j)
    curvature = 2 * np.pi / L + sp.ds(theta - 2 * np.pi * sp.alpha)
    alpha = sp.alpha
    psi = 0.4 + 0.3 * np.cos(2 * np.pi * alpha) + 0.1 * np.sin(6 * np.pi * alpha)
    tension = 1.5 + 0.7 * np.sin(4 * np.pi * alpha)
    return sp, z, tangent, curvature, psi, tension


@pytest.fixture(scope="module")
def membrane():
    return make_membrane(N)


@pytest.fixture(scope="module")
def fine_membrane():
    """psi beyond [0, 1] makes B(psi(s)) change over a few hundredths of the length (the
    saturating law's fade): the discrete energy and force agree once that is resolved."""
    return make_membrane(8 * N)


def force(membrane, phys, psi, tension, tangential_sign=-1.0):
    sp, z, tangent, curvature, _, _ = membrane
    psi_s = sp.ds(psi)
    sigma = phasefield.line_tension(psi, psi_s, phys.a0, phys.epsilon)
    f = bending_force(curvature, psi, psi_s, tangent, phys, sp) + tension_force(tension + sigma, tangent, sp)
    if tangential_sign > 0:   # the published sign: +mu psi_s instead of -mu psi_s in dE/dgamma
        mu = phasefield.chemical_potential(psi, sp.ds2(psi), curvature, phys.bending_prime(psi), phys.a0, phys.epsilon)
        f = f - 2 * mu * psi_s * tangent
    return f


def directional_derivative(membrane, phys, psi, tension, phi, eta=3e-4):
    """Fourth-order central difference of the discrete energy along phi (truncation ~1e-9 at eta = 3e-4)."""
    sp, z = membrane[0], membrane[1]
    E = lambda e: sum(energy_terms(z + e * phi, psi, phys, sp, tension))  # noqa: E731
    return (8 * (E(eta) - E(-eta)) - (E(2 * eta) - E(-2 * eta))) / (12 * eta)


#: psi beyond [0, 1] on both sides, by up to two widths of the saturating law (bending.py)
WIDE = dict(centre=0.5, amplitude=0.6)

CASES = {
    "bending, constant B": (dict(a0=0.0, B1=1.0, B2=1.0), "zero_psi", False),
    "bending, B(psi)": (dict(a0=0.0), "psi", False),
    "bending, linear B(psi) beyond [0, 1]": (dict(a0=0.0, bending_law="linear"), "wide", False),
    "bending, saturating B(psi) beyond [0, 1]": (dict(a0=0.0, bending_law="saturating"), "wide", False),
    "line energy": (dict(a0=100.0, B1=1e-14, B2=1e-14), "psi", False),
    "tension": (dict(a0=0.0, B1=1e-14, B2=1e-14), "psi", True),
    "all terms": (dict(), "psi", True),
    "all terms, saturating beyond [0, 1]": (dict(bending_law="saturating"), "wide", True),
}


def wide_psi(sp):
    """psi in [-0.1, 1.1]: both ends outside [0, 1], through the saturating law's whole fade."""
    return WIDE["centre"] + WIDE["amplitude"] * np.cos(2 * np.pi * sp.alpha) + 0.05 * np.sin(6 * np.pi * sp.alpha)


@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.parametrize("direction", ["normal", "tangential"])
@pytest.mark.parametrize("m", [2, 5])
def test_force_is_minus_the_energy_gradient(membrane, fine_membrane, name, direction, m):
    kwargs, which_psi, with_tension = CASES[name]
    membrane = fine_membrane if which_psi == "wide" else membrane
    sp, z, tangent, curvature, psi, tension = membrane
    N = sp.N
    phys = Physics(**kwargs)
    psi = {"zero_psi": np.zeros(N), "wide": wide_psi(sp)}.get(which_psi, psi)
    tension = tension if with_tension else np.zeros(N)
    frame = -1j * tangent if direction == "normal" else tangent
    phi = np.cos(2 * np.pi * m * sp.alpha + 0.3) * frame
    dE = directional_derivative(membrane, phys, psi, tension, phi)
    work = -np.sum(np.real(np.conj(force(membrane, phys, psi, tension)) * phi)) * L / N
    scale = max(abs(dE), 1e-3 * np.sum(np.abs(force(membrane, phys, psi, tension))) * L / N)
    assert abs(dE - work) <= 1e-7 * scale, (dE, work)


def test_the_published_tangential_sign_fails_the_check(membrane):
    sp, z, tangent, curvature, psi, tension = membrane
    phys = Physics()
    phi = np.cos(2 * np.pi * 5 * sp.alpha + 0.3) * tangent
    dE = directional_derivative(membrane, phys, psi, tension, phi)
    right = -np.sum(np.real(np.conj(force(membrane, phys, psi, tension)) * phi)) * L / N
    wrong = -np.sum(np.real(np.conj(force(membrane, phys, psi, tension, tangential_sign=+1)) * phi)) * L / N
    assert abs(dE - right) < 1e-7 * abs(dE)
    assert abs(dE - wrong) > 0.1 * abs(dE)


@pytest.mark.parametrize("law", ["linear", "saturating"])
@pytest.mark.parametrize("which_psi", ["psi", "wide"])
def test_chemical_potential_is_the_energy_derivative_in_psi(membrane, fine_membrane, law, which_psi):
    """int mu v ds = d/d eta (E_b + E_psi)(psi + eta v) at a fixed curve, mu = B'(psi)/2 H^2 +
    (a0/eps)(g'(psi) - eps^2 psi_ss), for both bending laws and psi inside and beyond [0, 1]."""
    sp, z, tangent, curvature, psi, tension = fine_membrane if which_psi == "wide" else membrane
    N = sp.N
    psi = wide_psi(sp) if which_psi == "wide" else psi
    phys = Physics(bending_law=law)
    mu = phasefield.chemical_potential(psi, sp.ds2(psi), curvature, phys.bending_prime(psi), phys.a0, phys.epsilon)
    for m in (1, 3, 7):
        v = np.cos(2 * np.pi * m * sp.alpha + 0.2)
        eta = 1e-4
        E = lambda e: sum(energy_terms(z, psi + e * v, phys, sp)[:2])  # noqa: E731
        dE = (8 * (E(eta) - E(-eta)) - (E(2 * eta) - E(-2 * eta))) / (12 * eta)
        assert abs(dE - np.sum(mu * v) * L / N) <= 1e-7 * np.sum(np.abs(mu * v)) * L / N, (m, dE)


def test_the_saturating_law_is_the_linear_one_on_zero_one_and_bounded_outside():
    from hpcves.model import bending

    inside = np.linspace(0.0, 1.0, 101)
    linear, saturating = Physics(bending_law="linear"), Physics(bending_law="saturating")
    assert np.array_equal(saturating.bending(inside), linear.bending(inside))
    assert saturating.bending_prime(inside) == linear.bending_prime(inside) == -0.9
    assert saturating.bending_second(inside) is None
    beyond = np.linspace(-5.0, 6.0, 2001)
    B = saturating.bending(beyond)
    low, high = bending.stiffness_bounds(1.0, 0.1, "saturating", 0.05)
    assert 0.05 < low <= B.min() and B.max() <= high < 1.05
    assert np.all(np.diff(B) <= 0)                                   # monotone, like the linear law
    assert linear.bending(beyond).min() < 0                          # where the linear law gives out
    # B' and B'' continuous through the ends: the one-sided limits agree
    for end in (0.0, 1.0):
        near = np.array([end - 1e-9, end + 1e-9, 0.5])
        assert np.allclose(np.atleast_1d(saturating.bending_prime(near))[:2], -0.9, rtol=0, atol=1e-12)
        assert np.allclose(saturating.bending_second(near)[:2], 0.0, atol=1e-12)
    with pytest.raises(Exception, match="bending_width"):
        Physics(bending_width=0.2)                                  # would reach B <= 0
