"""Membrane energy and the force f = -dE/dgamma it exerts on the fluid.

    E = E_b + E_psi + E_p,  E_b = 1/2 int B(psi) H^2 ds,  E_p = int Lambda ds.

For a normal displacement phi n and a tangential one phi s of the material
points (psi carried along) the first variations are

    dE = int [ -(B H)_ss - B/2 H^3 + (sigma + Lambda) H ] phi ds     (normal)
    dE = int [ -mu psi_s - Lambda_s ] phi ds                         (tangential)

with sigma = (a0/eps)(g - eps^2/2 psi_s^2) and mu the chemical potential. SPEC
section 1 warns that the published tangential term has +mu psi_s; the sign
here follows from the variation and is pinned by the finite-difference tests
in tests/test_forces.py. The line-energy part of both components is exactly
the force of an extra tension sigma:  -(sigma H) n + sigma_s s = d(sigma s)/ds.
So the force is

    f = [ (B H)_ss + B/2 H^3 ] n + B'/2 H^2 psi_s s  +  d(Lambda~ s)/ds,

with the *effective* tension Lambda~ = Lambda + sigma, which is what the
inextensibility constraint determines. Diagnostics report the Lagrange
multiplier Lambda = Lambda~ - sigma itself.
"""
from __future__ import annotations

import numpy as np

from hpcves.model import phasefield
from hpcves.model.params import Physics
from hpcves.numerics.spectral import Spectral


def bending_force(curvature, psi, psi_s, tangent, physics: Physics, sp: Spectral):
    """Force of the bending energy with psi-dependent stiffness (complex, per unit length).

    f_b = [ (B H)_ss + B/2 H^3 ] n + B'/2 H^2 psi_s s,  n = -i s.
    """
    B = physics.bending(psi)
    BH = B * curvature
    normal_part = sp.ds2(BH)
    normal_part += 0.5 * (BH * curvature) * curvature
    density = np.empty_like(tangent)
    np.multiply(curvature * curvature, 0.5 * physics.bending_prime(psi) * psi_s, out=density.real)
    np.negative(normal_part, out=density.imag)
    density *= tangent
    return density


def tension_force(tension, tangent, sp: Spectral):
    """f = d(Lambda s)/ds = Lambda_s s - Lambda H n (complex)."""
    return sp.ds_complex(tension * tangent)


def energy_terms(z, psi, physics: Physics, sp: Spectral, tension=None):
    """(E_b, E_psi, E_p) of the discrete curve z with phase psi at its nodes.

    The curve need not be parametrised by arclength: |dz/dalpha| is measured,
    H = Im(conj(z') z'') / |z'|^3 and psi_s = psi_alpha / |z'|. This is the
    discrete energy that the force is checked against.
    """
    dz = sp.ds_complex(z) * sp.length           # dz/dalpha
    d2z = sp.ds_complex(dz) * sp.length
    speed = np.abs(dz)
    curvature = np.imag(np.conj(dz) * d2z) / speed**3
    psi_s = sp.ds(psi) * sp.length / speed
    weight = speed / sp.N                      # ds = |z'| dalpha, trapezoid
    E_b = 0.5 * np.sum(physics.bending(psi) * curvature**2 * weight)
    a0, eps = physics.a0, physics.epsilon
    E_psi = (a0 / eps) * np.sum((phasefield.double_well(psi) + 0.5 * eps**2 * psi_s**2) * weight)
    E_p = 0.0 if tension is None else np.sum(tension * weight)
    return E_b, E_psi, E_p


def bending_energy(curvature, psi, physics: Physics, length: float) -> float:
    """E_b = 1/2 int B(psi) H^2 ds on an arclength-parametrised curve."""
    return 0.5 * length * float(np.mean(physics.bending(psi) * curvature**2))


def phase_energy(psi, psi_s, physics: Physics, length: float) -> float:
    """E_psi = (a0/eps) int (g + eps^2/2 psi_s^2) ds on an arclength-parametrised curve."""
    a0, eps = physics.a0, physics.epsilon
    return length * (a0 / eps) * float(np.mean(phasefield.double_well(psi) + 0.5 * eps**2 * psi_s**2))
