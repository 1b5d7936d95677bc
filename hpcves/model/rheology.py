"""The stress a vesicle adds to the suspension: its stresslet, and the coefficients made from it.

A dilute suspension of area fraction phi has the mean deviatoric stress 2 eta E + (phi / A) Sigma
(Batchelor, J. Fluid Mech. 41, 545, 1970, in two dimensions), with the vesicle's stresslet

    Sigma_ij = 1/2 oint (Df_i x_j + Df_j x_i) ds + (lambda - 1) eta oint (u_i n_j + u_j n_i) ds,

Df = (sigma_out - sigma_in) . n the jump of the fluid traction across the membrane, x measured from
the centroid, n the outward normal, u the membrane velocity and lambda the viscosity ratio. The
membrane is massless, so Df = -f, f the force it exerts on the fluid (forces.py; the single layer of
flow.py is driven by f). Derivation: the particle's share of the mean stress is the integral over
the region inside the membrane's outer side of sigma - 2 eta e; the divergence theorem turns the
traction there into oint (sigma_in . n + Df) x ds, and 2 lambda eta e inside into
lambda eta oint (u n + n u) ds. The isotropic part is a pressure and is dropped: only the deviatoric
part is measured, in the two numbers a traceless symmetric 2x2 tensor has,

    Sigma_xy    and    Sigma_xx - Sigma_yy.

In simple shear u_inf = S (y, 0) (eta = 1, the model's units) they give the intrinsic viscosity and
the first normal-stress coefficient,

    [eta] = Sigma_xy / (S A),        N1 = (Sigma_xx - Sigma_yy) / (S A),

A the enclosed area: eta_eff = eta (1 + [eta] phi) and N1 phi eta S is the suspension's first
normal-stress difference. A rigid disk has [eta] = 2 (the two-dimensional Einstein coefficient)
and N1 = 0; a rigid ellipse, semi-axes a > b, long axis at theta to the flow, has

    [eta] = K_n sin^2 2 theta + K_s cos^2 2 theta,    N1 = (K_n - K_s) sin 4 theta,
    K_n = (a + b)^2 / (2 a b),    K_s = (a + b)^2 / (a^2 + b^2)

(:func:`rigid_ellipse`; derived in docs/numerics.md, "Rheology").
"""
from __future__ import annotations

import math

import numpy as np


def stresslet(z: np.ndarray, normal: np.ndarray, force: np.ndarray, velocity: np.ndarray, length: float,
              viscosity_ratio: float = 1.0) -> tuple[float, float]:
    """(Sigma_xy, Sigma_xx - Sigma_yy) of a membrane whose nodes ``z`` (complex, equispaced in
    arclength over ``length``) exert the force density ``force`` on the fluid and move with
    ``velocity``; ``normal`` is the outward normal (all complex, x + i y).

    Sigma = -1/2 oint (f x + x f) ds + (lambda - 1) oint (u n + n u) ds (eta = 1), by the trapezoid
    rule (spectrally accurate on a smooth closed curve). x is taken from the nodes' mean: f has no
    net force (up to discretisation) and oint n ds = 0, so the origin does not matter.
    """
    weight = length / z.size
    x = z - z.mean()
    fx, fy, xx, xy = force.real, force.imag, x.real, x.imag
    shear = -0.5 * np.sum(fx * xy + fy * xx) * weight
    normal_difference = -np.sum(fx * xx - fy * xy) * weight
    if viscosity_ratio != 1.0:
        ux, uy, nx, ny = velocity.real, velocity.imag, normal.real, normal.imag
        contrast = (viscosity_ratio - 1.0) * weight
        shear += contrast * np.sum(ux * ny + uy * nx)
        normal_difference += 2.0 * contrast * np.sum(ux * nx - uy * ny)
    return float(shear), float(normal_difference)


def coefficients(shear: float, normal_difference: float, shear_rate: float, area: float) -> tuple[float, float]:
    """([eta], N1) = (Sigma_xy, Sigma_xx - Sigma_yy) / (S A)."""
    scale = shear_rate * area
    if scale == 0.0:
        return math.nan, math.nan
    return shear / scale, normal_difference / scale


def rigid_ellipse(a: float, b: float, theta) -> tuple:
    """([eta], N1) of a rigid ellipse with semi-axes a, b, its a-axis at ``theta`` to the flow, in
    simple shear; from the equivalent-inclusion solution (Eshelby's tensor of an elliptic cylinder in
    an incompressible medium, the inclusion's strain rate set to zero; docs/numerics.md)."""
    K_n = (a + b) ** 2 / (2.0 * a * b)
    K_s = (a + b) ** 2 / (a * a + b * b)
    two = 2.0 * np.asarray(theta, dtype=float)
    return K_n * np.sin(two) ** 2 + K_s * np.cos(two) ** 2, (K_n - K_s) * np.sin(2.0 * two)
