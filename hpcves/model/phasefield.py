"""Ginzburg-Landau line energy and the Cahn-Hilliard equation on the membrane.

    E_psi = (a0/eps) int ( g(psi) + eps^2/2 psi_s^2 ) ds,   g = psi^2 (1 - psi)^2 / 4,
    mu    = dE/dpsi = B'(psi)/2 H^2 + (a0/eps) ( g'(psi) - eps^2 psi_ss ),
    psi_t = d/ds ( nu d mu / ds )        (material coordinates, nu constant;
                                          the solver adds -V psi_s in its node frame).

Time stepping (see :mod:`hpcves.solver.timestepping`) treats the linear stiff part
nu (a0 eps k^4 + (a0/eps) s k^2) implicitly, where s is the linear
stabilisation constant of the double-well term, and the rest explicitly.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import lapack

from hpcves.numerics.reductions import maximum, minimum
from hpcves.numerics.runs import periodic_runs


def double_well(psi):
    """g(psi) = psi^2 (1 - psi)^2 / 4."""
    return 0.25 * psi**2 * (1.0 - psi) ** 2


def double_well_prime(psi):
    """g'(psi) = psi (1 - psi) (1 - 2 psi) / 2 = u (u^2 - 1/4), u = psi - 1/2 (four passes)."""
    u = psi - 0.5
    g = u * u
    g -= 0.25
    g *= u
    return g


def double_well_second(psi):
    """g''(psi) = (1 - 6 psi + 6 psi^2) / 2."""
    return 0.5 * (1.0 - 6.0 * psi * (1.0 - psi))


def line_tension(psi, psi_s, a0, eps):
    """sigma = (a0/eps) (g(psi) - eps^2/2 psi_s^2): the line energy acts as this extra tension."""
    return (a0 / eps) * (double_well(psi) - 0.5 * eps**2 * psi_s**2)


def chemical_potential(psi, psi_ss, curvature, dbending, a0, eps):
    """mu = B'/2 H^2 + (a0/eps)(g'(psi) - eps^2 psi_ss).

    Built in place on the array that :func:`double_well_prime` returns.
    """
    well = double_well_prime(psi)
    well *= a0 / eps
    well += (0.5 * dbending) * (curvature * curvature)
    well -= (a0 * eps) * psi_ss
    return well


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


def domains_phase(psi_bar, delta, coordinate, domains: int, center: float):
    """psi(alpha, 0) = psi_bar + delta cos(2 pi m (a - a0)): m soft bumps evenly spaced, the first centred
    at a = a0, which the spinodal stage sharpens into m soft domains."""
    return psi_bar + delta * np.cos(2.0 * np.pi * domains * (np.asarray(coordinate) - center))


#: the Fourier modes k = 1 .. RANDOM_MODES that a random initial phase perturbs
RANDOM_MODES = 8


def random_phase(psi_bar, delta, coordinate, seed: int):
    """psi(alpha, 0) = psi_bar + 4 delta sum_k (a_k cos 2 pi k a + b_k sin 2 pi k a) / sum_k |(a_k, b_k)|,
    k = 1 .. RANDOM_MODES, (a_k, b_k) standard normal from numpy's default generator seeded with ``seed``:
    the same pattern at every N, |psi - psi_bar| <= 4 delta like the published one, mean psi_bar."""
    coefficients = np.random.default_rng(seed).standard_normal((RANDOM_MODES, 2))
    scale = 4.0 * delta / np.hypot(coefficients[:, 0], coefficients[:, 1]).sum()
    a = 2.0 * np.pi * np.outer(np.asarray(coordinate), np.arange(1, RANDOM_MODES + 1))
    return psi_bar + scale * (np.cos(a) @ coefficients[:, 0] + np.sin(a) @ coefficients[:, 1])


#: g''(psi) < 0 exactly for psi strictly between these roots of 1 - 6 psi + 6 psi^2,
#: i.e. for |psi - 1/2| < SPINODAL_HALF_WIDTH
SPINODAL_HALF_WIDTH = np.sqrt(3.0) / 6.0
SPINODAL = (0.5 - SPINODAL_HALF_WIDTH, 0.5 + SPINODAL_HALF_WIDTH)


def longest_spinodal_run(psi, length):
    """Arclength of the longest stretch (periodic) on which g''(psi) < 0."""
    runs = periodic_runs((psi > SPINODAL[0]) & (psi < SPINODAL[1]))
    return float(max((count for _, count in runs), default=0)) * length / psi.size


#: a linearly implicit step whose result leaves this range is rejected (see :func:`plausible`)
PLAUSIBLE = (-0.1, 1.1)


def plausible(psi) -> bool:
    """Whether a linearly implicit Cahn-Hilliard step gave a sane psi (within PLAUSIBLE).

    ``applicable`` looks at the spinodal stretches *before* the step, but a
    stretch just short enough to pass can still carry growth rates near
    1/dt: c I + J is then nearly singular and the step overshoots wildly
    (psi_bar = 0.5, S = 80, dt = 1e-3, step 13: J's lowest eigenvalue -1409
    against c = 1500, psi jumped to [-0.44, 1.35]). Healthy steps keep psi
    within about [-0.005, 1.005], so an overshoot beyond 0.1 means the step
    is not to be trusted and the robust stabilised Euler step is taken instead.
    """
    return PLAUSIBLE[0] <= minimum(psi) and maximum(psi) <= PLAUSIBLE[1]


#: |g''(psi*) - 1/2| below which the Jacobian keeps the bulk value g'' = 1/2 (see LinearizedImplicit)
CUTOFF = 0.02


class LinearizedImplicit:
    """Linearly implicit solves for the Cahn-Hilliard part of a multistep step.

    The stiff part of psi_t = nu D^2 mu is its Jacobian at a predicted state psi*,

        J(psi*) = nu ( a0 eps D^4 - (a0/eps) D^2 diag g''(psi*) ),

    with D^2, D^4 the spectral differentiation matrices (arclength). Where the bending
    law bends (the saturating law outside [0, 1], bending.py) mu's B'(psi) H^2 / 2 adds
    B''(psi*) H^2 / 2 to (a0/eps) g''(psi*), H the curvature at the current level: without
    it psi near the bounds jitters from step to step. A step solves
    (c I + J + V D) psi_new = explicit + J psi*, V D an implicit uniform advection.
    Taking the local g'' (instead of a constant stabilisation) leaves only
    O((psi_new - psi*)^2) of the stiff double-well term explicit, which is what
    makes the phase dynamics accurate at time steps far above the interface
    relaxation time.

    In the bulk phases g'' = 1/2, so J is a circulant matrix (the bulk part) plus
    D^2 times a diagonal that is non-zero only across interfaces. Where
    |g'' - 1/2| <= ``cutoff`` (0.02: the far tails of the interfaces and the
    slight over- and undershoots of the bulk) the Jacobian keeps the bulk value
    -- any J gives a consistent linearly implicit step, and the explicit rest
    stays a few per cent of the implicit part, mode by mode. The rest is a rank-p
    correction (p ~ 56 of N = 128 for two interfaces) solved by the Woodbury
    identity: FFTs and a p x p LU instead of an N x N one (42 us instead of
    140-190 us at N = 128). At dt = 1e-3 the S = 80 phase-treading period is the
    same to 1e-6 with and without the cutoff. Since 1^T D = 1^T D^2 = 0 the
    solve keeps int psi ds as the right-hand side prescribes, up to round-off,
    which the solver removes by re-imposing the mass.

    The Jacobian is safe to use when every stretch with g'' < 0 is short: a
    region of length l with g'' = -kappa carries negative eigenvalues of J only
    for wavenumbers k < sqrt(kappa)/eps, which need l > pi eps / sqrt(kappa).
    Equilibrium interfaces have spinodal cores of length 4 sqrt(2) eps atanh(0.58)
    ~ 3.8 eps < 2 pi eps; a mixed state (the initial condition) has long ones,
    where c I + J can be nearly singular, and so can a freshly separated state
    that still overshoots [0, 1]. :meth:`applicable` tells which.
    """

    def __init__(self, sp, mobility, a0, eps, cutoff=CUTOFF):
        self.N = sp.N
        self.cutoff = cutoff
        self._fft = sp.fft
        self._c2 = mobility * a0 / eps
        self._bending_scale = eps / a0 if a0 > 0 else 0.0   # B'' H^2 / 2 in units of (a0/eps) g''
        self._k2 = sp.k2                                        # symbol of D^2 (Nyquist kept)
        self._ik = sp.ik                                        # symbol of D (Nyquist dropped)
        self._bulk = (mobility * a0 * eps) * sp.k2**2 - 0.5 * self._c2 * sp.k2   # J at g'' = 1/2
        self._c2_k2 = self._c2 * sp.k2
        self._diagonal = {}                          # c -> c + bulk symbol
        max_run = 2.0 * np.pi * eps                 # pi eps / sqrt(max(-g'')) with max(-g'') = 1/4
        # a stretch is too long once it has this many points (longest_spinodal_run > max_run)
        points = 1
        while points <= self.N and float(points) * sp.length / self.N <= max_run:
            points += 1
        self._run_points = points
        self._too_long = b"\x01" * points

    def applicable(self, psi_star) -> bool:
        """Short spinodal stretches only (longest_spinodal_run <= 2 pi eps), and no
        overshoot beyond [-0.05, 1.05].

        A stretch is too long when ``_run_points`` consecutive points (periodically)
        lie in the spinodal range: the flags of the points, as bytes, then contain
        that many ones in a row (a substring search: 0.5 us against 4 for a moving
        sum over the window at N = 128).
        """
        deviation = np.abs(psi_star - 0.5)
        if not maximum(deviation) <= 0.55:
            return False
        points = self._run_points
        if points > self.N:
            return True
        flags = (deviation < SPINODAL_HALF_WIDTH).tobytes()          # b"\x00" / b"\x01" per point
        return self._too_long not in flags + flags[: points - 1]

    def _excess(self, psi_star, bending=None):
        """g''(psi*) - 1/2 = 3 psi* (psi* - 1), plus (eps/a0) ``bending`` where the bending law bends."""
        e = 3.0 * psi_star * (psi_star - 1.0)
        if bending is not None:
            e += self._bending_scale * bending
        return e

    def excess_curvature(self, psi_star, truncated=True, bending=None):
        """e = g''(psi*) - 1/2 + (eps/a0) B''(psi*) H^2 / 2, set to 0 where |e| <= cutoff if ``truncated``
        (as the solve does). ``bending`` = B''(psi*) H^2 / 2, or None where B'' = 0 (the linear law)."""
        e = self._excess(psi_star, bending)
        if truncated:
            e[np.abs(e) <= self.cutoff] = 0.0
        return e

    def jacobian(self, psi_star, truncated=True, bending=None):
        """J(psi*) as a dense matrix (for checks; the solve never forms it)."""
        eye = np.eye(self.N)
        bulk = np.array([self._fft.irfft(self._bulk * self._fft.rfft(row)) for row in eye]).T
        D2 = np.array([self._fft.irfft(self._k2 * self._fft.rfft(row)) for row in eye]).T
        return bulk - self._c2 * D2 * self.excess_curvature(psi_star, truncated, bending)

    def solve_linearized(self, psi_star, c, explicit, advection=0.0, bending=None):
        """psi_new with (c I + J + V D) psi_new = explicit + J psi*, J = J(psi*) truncated,
        V = ``advection`` (the uniform advection psi_t = -V psi_s, implicit as a whole),
        ``bending`` = B''(psi*) H^2 / 2 where the bending law bends (see :meth:`excess_curvature`).

        Woodbury: c I + J + V D = K + U W^T with K circulant (symbol
        kappa = c + nu a0 eps k^4 + nu (a0/eps) k^2 / 2 + i k V) and
        U W^T = -nu (a0/eps) D^2 E_P diag(e_P) E_P^T, P the p points where e != 0.
        With z = K^{-1} rhs and Q = K^{-1} D^2 (circulant, one transform):
        psi_new = z + nu (a0/eps) Q E_P y, (I - nu (a0/eps) diag(e_P) Q_PP) y = e_P z_P,
        solved as (diag(1/e_P) - nu (a0/eps) Q_PP) y = z_P (rows divided by e_P != 0:
        no p x p scaling pass).
        """
        fft = self._fft
        return self.solve_spectral(psi_star, fft.rfft(psi_star), c, fft.rfft(explicit), advection, bending)

    def solve_spectral(self, psi_star, psi_star_hat, c, explicit_hat, advection=0.0, bending=None):
        """:meth:`solve_linearized` given the rfft spectra of psi* and of the explicit side."""
        fft, N = self._fft, self.N
        e = self._excess(psi_star, bending)
        P = (np.abs(e) > self.cutoff).nonzero()[0]          # where excess_curvature keeps e
        rhs_hat = explicit_hat + self._bulk * psi_star_hat
        if c not in self._diagonal:
            self._diagonal = {c: c + self._bulk}             # the same c every step
        kappa = self._diagonal[c] + advection * self._ik
        if P.size == 0:
            return fft.irfft(rhs_hat / kappa)
        e_P = e[P]
        w = np.zeros(N)
        w[P] = e_P * psi_star[P]
        rhs_hat -= self._c2_k2 * fft.rfft(w)
        z = fft.irfft(rhs_hat / kappa)
        Q_symbol = self._c2_k2 / kappa                        # nu (a0/eps) K^{-1} D^2
        minus_q = fft.irfft(-Q_symbol)
        # capacitance diag(1/e_P) - Q_PP, Q_PP[a, b] = q[(P_a - P_b) mod N] read from q[1:], q end to end
        capacitance = np.concatenate((minus_q[1:], minus_q)).take((P + (N - 1))[:, None] - P)
        capacitance.reshape(-1)[:: P.size + 1] += 1.0 / e_P
        lu, piv, y, info = lapack.dgesv(capacitance, z[P], overwrite_a=1, overwrite_b=1)
        if info != 0:
            raise ArithmeticError("Cahn-Hilliard step: singular linear system")
        w[:] = 0.0
        w[P] = y
        return z + fft.irfft(Q_symbol * fft.rfft(w))
