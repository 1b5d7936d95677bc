"""Membrane velocity: Stokes flow driven by the membrane force, with the tension
that makes the flow locally inextensible.

    u = u_inf + SLP[ f_b + d(Lambda~ s)/ds ],     u_inf(x) = S (y, 0),
    s . du/ds = 0   on the membrane                (local inextensibility).

The constraint is linear in the effective tension Lambda~ (see
:mod:`hpcves.model.forces`). With B Lambda = d(Lambda s)/ds, i.e.
B = [D_s diag(s_x); D_s diag(s_y)], and the constraint operator
s . D_s = [diag(s_x) D_s, diag(s_y) D_s] = -B^T, the tension solves

    A Lambda~ = s . D_s (u_inf + G f_b),     A = B^T G B,

with G the assembled single-layer matrix. A is symmetric positive definite
(G is, on forces of zero total, and B has no kernel). D_s G D_s is formed in
closed form from the kernels' analytic derivatives
(:meth:`hpcves.numerics.quadrature.StokesSLP.constraint_matrix`, O(N^2) elementwise)
and factorised by Cholesky, O(N^3/6). That A differs from the discrete B^T G B
by the spectral error of the derivatives (9e-13 relative at psi_bar = 0.3,
Delta = 0.194, N = 128, which leaves a stretching of ~6e-10 of what the
tension cancels; 1e-4 on the tips of Delta = 2.3 at N = 64), so the
tension is refined against the exact discrete constraint (iterative refinement
with the same factor): each pass costs one matvec and shrinks the residual
s . du/ds by about that relative error times the condition number. Passes stop
once it is below REFINEMENT_TOLERANCE = 1e-8 of the stretching s . du0/ds that
the tension cancels, or stops falling (round-off). Refining further, to round-off
(1e-13), changed theta(t) by 4e-14 and psi by 9e-13 over t = 1 (N = 128, dt =
1e-3; psi_bar = 0.3, S = 80 and psi_bar = 0.5, Delta = 0.94, S = 40), where
halving dt moves theta by 2e-3 and 3e-2 (docs/numerics.md), and cost a pass (~30 us)
every step; now 95 % of the steps at psi_bar = 0.3, Delta = 0.194 take none,
70 % at Delta = 0.94 take one, and the tips of Delta = 2.3 one (N = 128) or
two (N = 64). A residual still above UNRESOLVED = 1e-6 of it means the closed form is
far from B^T G B, i.e. the shape is not resolved, and stops the run like a
divergence. (Forming D_s G D_s by a 2-D FFT of the blocks
instead cost 3x more at N = 128; docs/numerics.md.)

With a viscosity contrast (physics.viscosity_ratio = lambda != 1) the velocity
solves ((1 + lambda)/2) u - D[u] = u_inf + SLP[...] instead, D the double layer
(numerics/double_layer.py); that system is not symmetric and is solved by GMRES, preconditioned
by the equal-viscosity solve (:meth:`MembraneFlow._solve_with_contrast`; docs/numerics.md,
"Viscosity contrast").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import blas, lapack

from hpcves.model.forces import bending_force, tension_force
from hpcves.model.geometry import Shape
from hpcves.model.params import Physics
from hpcves.numerics.double_layer import double_layer_matrix
from hpcves.numerics.krylov import gmres
from hpcves.numerics.quadrature import StokesSLP
from hpcves.numerics.reductions import largest_magnitude
from hpcves.numerics.spectral import Spectral


@dataclass(frozen=True)
class Flow:
    """The membrane velocity and what it took to compute it."""

    velocity: np.ndarray          # u at the membrane points (complex)
    tension_eff: np.ndarray       # Lambda~ = Lambda + sigma

    def stretching(self, tangent: np.ndarray, sp: Spectral) -> np.ndarray:
        """s . du/ds, zero for an inextensible membrane."""
        return np.real(np.conj(tangent) * sp.ds_complex(self.velocity))


class MembraneFlow:
    """Computes :class:`Flow` for a shape and a phase field."""

    REFINEMENT_TOLERANCE = 1e-8       # residual s . du/ds relative to the stretching of u0
    MAX_REFINEMENTS = 8
    UNRESOLVED = 1e-6                 # a residual above this after refining: the shape is not resolved
    GMRES_TOLERANCE = 1e-9            # |b - K x| / |b| of a viscosity contrast's solve
    MAX_ITERATIONS = 60               # GMRES iterations before the solve counts as diverged

    def __init__(self, physics: Physics, sp: Spectral):
        self.physics = physics
        self.sp = sp
        self.slp = StokesSLP(sp.N, sp.length)
        self._blocks = np.empty((3, sp.N, sp.N))
        self._A = np.empty((sp.N, sp.N))          # constraint matrix, factorised in place

    def _driving_flow(self, shape: Shape, psi: np.ndarray, psi_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(the assembled single-layer blocks, u0 = u_inf + G f_b): the flow before the tension."""
        blocks = self.slp.assemble(shape.z, shape.tangent, out=self._blocks)
        u0 = self.slp.apply(blocks, bending_force(shape.curvature, psi, psi_s, shape.tangent, self.physics, self.sp))
        u0 += self.physics.shear_rate * shape.z.imag
        return blocks, u0

    def solve(self, shape: Shape, psi: np.ndarray, psi_s: np.ndarray) -> Flow:
        """Velocity of the membrane and its effective tension."""
        if self.physics.contrast:
            return self._solve_with_contrast(shape, psi, psi_s)
        sp, slp = self.sp, self.slp
        tangent = shape.tangent
        conj_tangent = np.conj(tangent)
        blocks, u0 = self._driving_flow(shape, psi, psi_s)
        rhs = (conj_tangent * sp.ds_complex(u0)).real
        A = slp.constraint_matrix(tangent, shape.curvature, out=self._A)
        # A is symmetric and C-ordered: its transpose is the same matrix in the Fortran
        # order LAPACK wants (no copy), and LAPACK's lower Cholesky is the faster one there
        factor, info = lapack.dpotrf(A.T, lower=1, overwrite_a=1, clean=0)
        if info != 0:
            raise TensionSolveError.not_definite()
        tension = cholesky_solve(factor, rhs)
        u = u0 + slp.apply(blocks, tension_force(tension, tangent, sp))
        scale = largest_magnitude(rhs)
        previous = np.inf
        for refinements in range(self.MAX_REFINEMENTS + 1):
            residual = (conj_tangent * sp.ds_complex(u)).real       # = rhs - (B^T G B) tension
            size = largest_magnitude(residual)
            if size <= self.REFINEMENT_TOLERANCE * scale or size > 0.5 * previous \
                    or refinements == self.MAX_REFINEMENTS:           # converged, at round-off, or done
                break
            previous = size
            correction = cholesky_solve(factor, residual)
            tension += correction
            u += slp.apply(blocks, tension_force(correction, tangent, sp))
        if size > self.UNRESOLVED * scale:
            raise TensionSolveError.unresolved(size / scale)
        return Flow(velocity=u, tension_eff=tension)

    def _solve_with_contrast(self, shape: Shape, psi: np.ndarray, psi_s: np.ndarray) -> Flow:
        """The same with lambda = physics.viscosity_ratio != 1 (numerics/double_layer.py):

            K (u, Lambda~) = (c u - D u - G B Lambda~, s . D_s u) = (u_inf + G f_b, 0),   c = (1 + lambda)/2,

        by GMRES (numerics/krylov.py) to a relative residual of GMRES_TOLERANCE, right-preconditioned
        by the equal-viscosity solve with c u in place of c u - D u: P^{-1} (r_1, r_2) = (u, Lambda~)
        with A Lambda~ = s . D_s r_1 - c r_2 (A the factorised constraint matrix of :meth:`solve`) and
        u = (r_1 + G B Lambda~) / c, so that K P^{-1} (r_1, r_2) = (r_1 - D u, s . D_s u) and only D u
        is new each iteration. D gives back -(1 - lambda)/2 times a rigid motion (inextensible, so P
        leaves it alone): K P^{-1} maps rigid motions to 1/c times themselves, and the preconditioner
        M^{-1} = P^{-1} (I + (c - 1) Q Q^T), Q the orthonormal rigid motions at the nodes, maps them
        to themselves. D is compact (a smooth kernel): 5 to 9 iterations at Delta = 0.194 and 0.94
        (N = 128, lambda from 0.5 to 10; docs/numerics.md). The closed-form A differs from the
        discrete B^T G B only in how fast the iteration converges, not in what it converges to."""
        sp, phys, slp, N = self.sp, self.physics, self.slp, self.sp.N
        c = 0.5 * (1.0 + phys.viscosity_ratio)
        tangent = shape.tangent
        conj_tangent = np.conj(tangent)
        blocks, u0 = self._driving_flow(shape, psi, psi_s)
        D = double_layer_matrix(shape.z, tangent, shape.curvature, sp.length / N, phys.viscosity_ratio)
        A = slp.constraint_matrix(tangent, shape.curvature, out=self._A)
        factor, info = lapack.dpotrf(A.T, lower=1, overwrite_a=1, clean=0)
        if info != 0:
            raise TensionSolveError.not_definite()
        rigid = rigid_motions(shape.z)

        def stretching(u):
            return (conj_tangent * sp.ds_complex(u)).real

        def preconditioned(r):
            v = r[:2 * N] + (c - 1.0) * (rigid @ (r[:2 * N] @ rigid))
            r1 = v[:N] + 1j * v[N:]
            tension = cholesky_solve(factor, stretching(r1) - c * r[2 * N:])
            u = (r1 + slp.apply(blocks, tension_force(tension, tangent, sp))) / c
            image = np.concatenate([v - D @ np.concatenate([u.real, u.imag]), stretching(u)])
            return np.concatenate([u.real, u.imag, tension]), image

        x, residual, _ = gmres(preconditioned, np.concatenate([u0.real, u0.imag, np.zeros(N)]),
                               self.GMRES_TOLERANCE, self.MAX_ITERATIONS)
        u, tension = x[:N] + 1j * x[N:2 * N], x[2 * N:]
        if not residual <= self.GMRES_TOLERANCE:
            raise TensionSolveError.unconverged(residual)
        scale = largest_magnitude(stretching(u0)) / c
        size = largest_magnitude(stretching(u))
        if size > self.UNRESOLVED * scale:
            raise TensionSolveError.unresolved(size / scale)
        return Flow(velocity=u, tension_eff=tension)


def rigid_motions(z: np.ndarray) -> np.ndarray:
    """(2N, 3): the translations along x and y and the rotation about the nodes' mean, as real
    (u_x, u_y) columns, orthonormal (the rotation i (z - mean z) sums to zero along each axis)."""
    N = z.size
    out = np.zeros((2 * N, 3))
    out[:N, 0] = out[N:, 1] = 1.0 / np.sqrt(N)
    arm = z - z.mean()
    out[:N, 2], out[N:, 2] = -arm.imag, arm.real
    out[:, 2] /= np.sqrt(out[:, 2] @ out[:, 2])
    return out


def cholesky_solve(factor, b):
    """x with L L^T x = b, L = ``factor`` (lower, Fortran order): two triangular solves
    (BLAS dtrsv; 6.7 us against 8.7 for LAPACK's dpotrs at N = 128)."""
    return blas.dtrsv(factor, blas.dtrsv(factor, b, lower=1), lower=1, trans=1)


class TensionSolveError(ArithmeticError):
    """The tension system could not be solved (the computation is diverging)."""

    @classmethod
    def not_definite(cls) -> "TensionSolveError":
        return cls("the inextensibility system is not positive definite: the shape is no longer "
                   "resolved (reduce dt or increase N)")

    @classmethod
    def unresolved(cls, stretching: float) -> "TensionSolveError":
        """``stretching``: what the tension leaves of the stretching it cancels (relative)."""
        return cls(f"the tension leaves a stretching of {stretching:.1e} of what it cancels: "
                   "the shape is no longer resolved (reduce dt or increase N)")

    @classmethod
    def unconverged(cls, residual: float) -> "TensionSolveError":
        """``residual``: |b - K x| / |b| where GMRES stopped (viscosity contrast)."""
        return cls(f"the velocity of the viscosity contrast kept a residual of {residual:.1e} after "
                   f"{MembraneFlow.MAX_ITERATIONS} GMRES iterations: the shape is no longer resolved "
                   "(reduce dt or increase N)")
