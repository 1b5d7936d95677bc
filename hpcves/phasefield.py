"""Ginzburg-Landau line energy and the Cahn-Hilliard equation on the membrane.

    E_psi = (a0/eps) int ( g(psi) + eps^2/2 psi_s^2 ) ds,   g = psi^2 (1 - psi)^2 / 4,
    mu    = dE/dpsi = B'(psi)/2 H^2 + (a0/eps) ( g'(psi) - eps^2 psi_ss ),
    psi_t = d/ds ( nu d mu / ds )        (material coordinates, nu constant;
                                          the solver adds -V psi_s in its node frame).

Time stepping (see :mod:`hpcves.timestepping`) treats the linear stiff part
nu (a0 eps k^4 + (a0/eps) s k^2) implicitly, where s is the linear
stabilisation constant of the double-well term, and the rest explicitly.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import lapack


def double_well(psi):
    """g(psi) = psi^2 (1 - psi)^2 / 4."""
    return 0.25 * psi**2 * (1.0 - psi) ** 2


def double_well_prime(psi):
    """g'(psi) = psi (1 - psi) (1 - 2 psi) / 2."""
    return 0.5 * psi * (1.0 - psi) * (1.0 - 2.0 * psi)


def double_well_second(psi):
    """g''(psi) = (1 - 6 psi + 6 psi^2) / 2."""
    return 0.5 * (1.0 - 6.0 * psi * (1.0 - psi))


def line_tension(psi, psi_s, a0, eps):
    """sigma = (a0/eps) (g(psi) - eps^2/2 psi_s^2): the line energy acts as this extra tension."""
    return (a0 / eps) * (double_well(psi) - 0.5 * eps**2 * psi_s**2)


def chemical_potential(psi, psi_ss, curvature, dbending, a0, eps):
    """mu = B'/2 H^2 + (a0/eps)(g'(psi) - eps^2 psi_ss)."""
    return 0.5 * dbending * curvature**2 + (a0 / eps) * (double_well_prime(psi) - eps**2 * psi_ss)


def implicit_symbol(k, mobility, a0, eps, stabilization):
    """Fourier symbol lambda(k) >= 0 of the stiff linear part: psi_t = -lambda psi + ...

    lambda = nu (a0 eps k^4 + (a0/eps) s k^2).
    """
    k2 = k * k
    return mobility * (a0 * eps * k2 * k2 + (a0 / eps) * stabilization * k2)


def initial_phase(psi_bar, delta, coordinate):
    """psi(alpha, 0) = psi_bar + delta (3 cos 2 pi a + 0.5 cos 6 pi a + 0.5 cos 8 pi a) at coordinates a."""
    a = 2.0 * np.pi * np.asarray(coordinate)
    return psi_bar + delta * (3.0 * np.cos(a) + 0.5 * np.cos(3 * a) + 0.5 * np.cos(4 * a))


#: g''(psi) < 0 exactly for psi strictly between these roots of 1 - 6 psi + 6 psi^2
SPINODAL = (0.5 - np.sqrt(3.0) / 6.0, 0.5 + np.sqrt(3.0) / 6.0)


def longest_spinodal_run(psi, length):
    """Arclength of the longest stretch (periodic) on which g''(psi) < 0."""
    inside = (psi > SPINODAL[0]) & (psi < SPINODAL[1])
    if not inside.any():
        return 0.0
    outside = np.flatnonzero(~inside)
    if outside.size == 0:
        return float(length)
    gaps = np.diff(outside) - 1
    wrap = outside[0] + psi.size - 1 - outside[-1]
    return float(max(gaps.max(initial=0), wrap)) * length / psi.size


class LinearizedImplicit:
    """Linearly implicit solves for the Cahn-Hilliard part of a multistep step.

    The stiff part of psi_t = nu D^2 mu is its Jacobian at a predicted state psi*,

        J(psi*) = nu ( a0 eps D^4 - (a0/eps) D^2 diag g''(psi*) ),

    dense N x N with D^2, D^4 the spectral differentiation matrices (arclength).
    A step solves (c I + J + V D) psi_new = rhs by LU, V D being an implicit uniform
    advection (the solver's node frame); since 1^T D = 1^T D^2 = 1^T D^4 = 0 the
    solve keeps int psi ds as the right-hand side prescribes -- in exact
    arithmetic; round-off in J psi* (||J|| ~ 1e7) leaves ~1e-7, which the solver
    removes by re-imposing the mass. Taking the
    local g'' (instead of a constant stabilisation) leaves only O((psi_new - psi*)^2)
    of the stiff double-well term explicit, which is what makes the phase
    dynamics accurate at time steps far above the interface relaxation time.

    The Jacobian is safe to use when every stretch with g'' < 0 is short: a
    region of length l with g'' = -kappa carries negative eigenvalues of J only
    for wavenumbers k < sqrt(kappa)/eps, which need l > pi eps / sqrt(kappa).
    Equilibrium interfaces have spinodal cores of length 4 sqrt(2) eps atanh(0.58)
    ~ 3.8 eps < 2 pi eps; a mixed state (the initial condition) has long ones,
    where c I + J can be nearly singular, and so can a freshly separated state
    that still overshoots [0, 1]. :meth:`applicable` tells which.
    """

    def __init__(self, sp, mobility, a0, eps):
        N = sp.N
        self.D1 = np.array([sp.ds(row) for row in np.eye(N)]).T
        self.D2 = np.array([sp.ds2(row) for row in np.eye(N)]).T
        self._c2 = mobility * a0 / eps
        self._constant = (mobility * a0 * eps) * (self.D2 @ self.D2)
        self._max_run = 2.0 * np.pi * eps           # pi eps / sqrt(max(-g'')) with max(-g'') = 1/4
        self._length = sp.length

    def applicable(self, psi_star) -> bool:
        """Short spinodal stretches only, and no overshoot beyond [-0.05, 1.05]."""
        return (psi_star.min() >= -0.05 and psi_star.max() <= 1.05
                and longest_spinodal_run(psi_star, self._length) <= self._max_run)

    def jacobian(self, psi_star):
        """J(psi*) (a new array)."""
        J = np.multiply(self.D2, (-self._c2) * double_well_second(psi_star))
        J += self._constant
        return J

    def solve_linearized(self, psi_star, c, explicit, advection=0.0):
        """psi_new with (c I + J + V D) psi_new = explicit + J psi*, J = J(psi*), V = ``advection``.

        V D is the uniform advection psi_t = -V psi_s, implicit as a whole.
        """
        J = self.jacobian(psi_star)
        rhs = explicit + J @ psi_star
        if advection:
            J += advection * self.D1
        J.flat[:: J.shape[0] + 1] += c
        lu, piv, x, info = lapack.dgesv(J, rhs, overwrite_a=1, overwrite_b=1)
        if info != 0:
            raise ArithmeticError("Cahn-Hilliard step: singular linear system")
        return x
