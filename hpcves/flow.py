"""Membrane velocity: Stokes flow driven by the membrane force, with the tension
that makes the flow locally inextensible.

    u = u_inf + SLP[ f_b + d(Lambda~ s)/ds ],     u_inf(x) = S (y, 0),
    s . du/ds = 0   on the membrane                (local inextensibility).

The constraint is linear in the effective tension Lambda~ (see
:mod:`hpcves.forces`). With B Lambda = d(Lambda s)/ds, i.e.
B = [D_s diag(s_x); D_s diag(s_y)], and the constraint operator
s . D_s = [diag(s_x) D_s, diag(s_y) D_s] = -B^T, the tension solves

    A Lambda~ = s . D_s (u_inf + G f_b),     A = B^T G B,

with G the assembled single-layer matrix. A is symmetric positive definite
(G is, on forces of zero total, and B has no kernel); it is formed with FFT
derivatives along both axes of the kernels -- D_s G D_s costs O(N^2 log N),
not the O(N^3) of matrix products -- and solved by Cholesky, O(N^3/6), which
stays small against the rest up to N of a few hundred.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from .forces import bending_force, tension_force
from .geometry import Shape
from .params import Physics
from .quadrature import StokesSLP
from .spectral import BothSidesDerivative, Spectral


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

    def __init__(self, physics: Physics, sp: Spectral):
        self.physics = physics
        self.sp = sp
        self.slp = StokesSLP(sp.N, sp.length)
        self._dsd = BothSidesDerivative(sp, 3, backend=sp.fft.name)
        self._A = np.empty((sp.N, sp.N))          # constraint matrix, factorised in place

    def constraint_matrix(self, blocks: np.ndarray, tangent: np.ndarray) -> np.ndarray:
        """A = B^T G B (N x N, symmetric positive definite).

        With T_ab = D_s G_ab D_s and (c, s) = (cos, sin) theta,
        A = -[ diag(c) T_xx diag(c) + diag(s) T_yy diag(s) + diag(c) T_xy diag(s) + diag(s) T_xy diag(c) ].
        """
        if blocks is not self._dsd.input:
            self._dsd.input[...] = blocks
        T_xx, T_xy, T_yy = self._dsd()
        c, s = -tangent.real, tangent.imag          # the sign of A folded into c
        A = np.multiply(T_xx, c, out=self._A)
        A *= -c[:, None]
        T_yy *= s
        T_yy *= -s[:, None]
        A += T_yy
        T_xy *= s
        T_xy *= c[:, None]
        A += T_xy
        A += T_xy.T
        return A

    def solve(self, shape: Shape, psi: np.ndarray, psi_s: np.ndarray) -> Flow:
        """Velocity of the membrane and its effective tension."""
        sp, phys = self.sp, self.physics
        tangent = shape.tangent
        blocks = self.slp.assemble(shape.z, tangent, out=self._dsd.input)
        f_b = bending_force(shape.curvature, psi, psi_s, tangent, phys, sp)
        u0 = phys.shear_rate * shape.z.imag + StokesSLP.apply(blocks, f_b)
        rhs = np.real(np.conj(tangent) * sp.ds_complex(u0))
        A = self.constraint_matrix(blocks, tangent)
        factor, info = lapack.dpotrf(A, lower=1, overwrite_a=1, clean=0)
        if info != 0:
            raise TensionSolveError(
                "the inextensibility system is not positive definite: the shape is no longer "
                "resolved (reduce dt or increase N)")
        tension, info = lapack.dpotrs(factor, rhs, lower=1)
        u = u0 + StokesSLP.apply(blocks, tension_force(tension, tangent, sp))
        return Flow(velocity=u, tension_eff=tension)


class TensionSolveError(ArithmeticError):
    """The tension system could not be solved (the computation is diverging)."""
