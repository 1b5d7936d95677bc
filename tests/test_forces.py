"""Every term of the membrane force against a finite-difference derivative of the discrete energy.

dE = -int f . phi ds for smooth normal and tangential displacements phi of the
material points (psi carried along). SPEC section 1 warns that the published
tangential term has the wrong sign for mu psi_s; the last test shows that the
published sign does fail this check.
"""
import numpy as np
import pytest

from hpcves import geometry, phasefield
from hpcves.forces import bending_force, energy_terms, tension_force
from hpcves.params import Physics
from hpcves.spectral import Spectral

N, L = 64, 2.6442


@pytest.fixture(scope="module")
def membrane():
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


def force(membrane, phys, psi, tension, tangential_sign=-1.0):
    sp, z, tangent, curvature, _, _ = membrane
    psi_s = sp.ds(psi)
    sigma = phasefield.line_tension(psi, psi_s, phys.a0, phys.epsilon)
    f = bending_force(curvature, psi, psi_s, tangent, phys, sp) + tension_force(tension + sigma, tangent, sp)
    if tangential_sign > 0:   # the published sign: +mu psi_s instead of -mu psi_s in dE/dgamma
        mu = phasefield.chemical_potential(psi, sp.ds2(psi), curvature, phys.dbending, phys.a0, phys.epsilon)
        f = f - 2 * mu * psi_s * tangent
    return f


def directional_derivative(membrane, phys, psi, tension, phi, eta=3e-4):
    """Fourth-order central difference of the discrete energy along phi (truncation ~1e-9 at eta = 3e-4)."""
    sp, z = membrane[0], membrane[1]
    E = lambda e: sum(energy_terms(z + e * phi, psi, phys, sp, tension))  # noqa: E731
    return (8 * (E(eta) - E(-eta)) - (E(2 * eta) - E(-2 * eta))) / (12 * eta)


CASES = {
    "bending, constant B": (dict(a0=0.0, B1=1.0, B2=1.0), "zero_psi", False),
    "bending, B(psi)": (dict(a0=0.0), "psi", False),
    "line energy": (dict(a0=100.0, B1=1e-14, B2=1e-14), "psi", False),
    "tension": (dict(a0=0.0, B1=1e-14, B2=1e-14), "psi", True),
    "all terms": (dict(), "psi", True),
}


@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.parametrize("direction", ["normal", "tangential"])
@pytest.mark.parametrize("m", [2, 5])
def test_force_is_minus_the_energy_gradient(membrane, name, direction, m):
    sp, z, tangent, curvature, psi, tension = membrane
    kwargs, which_psi, with_tension = CASES[name]
    phys = Physics(**kwargs)
    psi = np.zeros(N) if which_psi == "zero_psi" else psi
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
