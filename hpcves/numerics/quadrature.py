"""Spectrally accurate single-layer Stokes potential on a closed curve.

    u(x_i) = 1/(4 pi) oint G(x_i - y) f(y) ds(y),   G(r) = -log|r| I + r r^T / |r|^2.

The log kernel is split (Kress; Martensen-Kussmaul) as

    log|r|^2 = log(4 sin^2(pi (a - b)))  +  log(|r|^2 / (4 sin^2(pi (a - b)))),

the first integrated exactly against the trigonometric interpolant of the
density (weights R_j, R. Kress, *Linear Integral Equations*, sec. 12.3), the
second smooth (diagonal limit log(|dz/dalpha|^2 / (4 pi^2)) = 2 log(L / 2 pi)
on an inextensible curve) and integrated by the trapezoid rule, as is the
bounded r r^T/|r|^2 part (diagonal limit s s^T).

With complex densities f = f_x + i f_y the kernel is
G f = (-log|r| + 1/2) f + 1/2 (r / conj r) conj(f), so the operator is the
real symmetric 2N x 2N matrix

    G = [[G_xx, G_xy], [G_xy, G_yy]] = [[M + P, Q], [Q, M - P]],
    M = w(-log|r| + 1/2),  P + i Q = w/2 r/conj(r),

acting on (f_x, f_y). Three symmetric N x N arrays are assembled per shape,
O(N^2), with as few elementwise passes as possible (12, of which one logarithm):

    M / w = base / w - log|r|^2,   P = w Re(r / conj r),   Q / 2 = w Im(r / conj r) / 2,

w = L / (8 pi N) (so c_log = -w), in this order; G_xx = M + P, G_yy = M - P,
G_xy = Q. Everything that depends only on N and L is precomputed. One matrix
product applies all three to a density (:meth:`StokesSLP.apply`);
:meth:`StokesSLP.cartesian` gives (G_xx, G_xy, G_yy).

The tension system of :mod:`hpcves.model.flow` needs T_ab = D_s G_ab D_s, with D_s the
spectral derivative (Nyquist dropped). Since (K D_s)_ij = -d/ds_j K(s_i, s_j),
T = -d_u d_v G(u, v) at (s_i, s_j): exact for the circulant Kress part
(precomputed) and spectrally accurate for the smooth rest, which has closed
forms (r = z_i - z_j, t the unit tangent, u = s_i, v = s_j):

    d_u d_v log|r|^2 = 2 Re(t_i t_j / r^2),
    d_u d_v log(4 sin^2(pi (u - v) / L)) = 2 (pi/L)^2 / sin^2(pi (u - v) / L),
    d_u d_v (r / conj r) = 2 Re(t_i conj t_j) / conj(r)^2 - 2 r conj(t_i t_j) / conj(r)^3,

and, on the diagonal (series of an arclength-parametrised curve, curvature H),
d_u d_v log(|r|^2 / (u - v)^2) -> H^2 / 6 and d_u d_v (r / conj r) -> (-H^2 + i H_s / 3) t^2.
See :meth:`StokesSLP.constraint_matrix`.
"""
from __future__ import annotations

import numpy as np


def kress_weights(N: int) -> np.ndarray:
    """Circulant matrix R with int_0^{2 pi} log(4 sin^2((t - tau)/2)) phi(tau) dtau = sum_j R_ij phi_j.

    R(t) = -(2 pi / n) sum_{m=1}^{n-1} cos(m t)/m - (pi / n^2) cos(n t),  n = N/2, t_j = 2 pi j / N.
    """
    n = N // 2
    t = 2.0 * np.pi * np.arange(N) / N
    m = np.arange(1, n)
    first = -(2.0 * np.pi / n) * (np.cos(np.outer(t, m)) / m).sum(axis=1) - (np.pi / n**2) * np.cos(n * t)
    return circulant(first)


def circulant(column: np.ndarray) -> np.ndarray:
    """The circulant matrix C_ij = column[(i - j) mod N]."""
    N = column.size
    return column[(np.arange(N)[:, None] - np.arange(N)[None, :]) % N]


class StokesSLP:
    """Single-layer Stokes operator on a curve of N material points and length L."""

    def __init__(self, N: int, length: float):
        self.N = N
        self.length = float(length)
        L = self.length
        c = 1.0 / (4.0 * np.pi)
        diff = np.arange(N)[:, None] - np.arange(N)[None, :]
        off = diff != 0
        sin2 = np.ones((N, N))
        sin2[off] = np.sin(np.pi * diff[off] / N) ** 2
        # M = c [ -(L/(4 pi)) R  - (L/(2N)) (log|r|^2 - log 4 sin^2)  + (L/N)/2 ]
        #   = c_log * log|r|^2 + base       (diagonal: log|r|^2 := 0, limit folded into base)
        c_log = -c * L / (2.0 * N)
        self._c_dir = c * L / (2.0 * N)          # weight of the r/conj(r) conj(f) part
        kress = -c * L / (4.0 * np.pi) * kress_weights(N)
        base = kress + self._c_dir * np.where(off, np.log(4.0 * sin2), 0.0) + self._c_dir
        base[~off] += c_log * 2.0 * np.log(L / (2.0 * np.pi))
        # constraint operator (module docstring): D_s K D_s of the Kress part is
        # circulant with symbol -k^2 K_hat; the smooth log part contributes
        # -c_log (2 Re(t_i t_j / r^2) - csc2) off the diagonal.
        k = 2.0 * np.pi * np.fft.fftfreq(N, 1.0 / N) / L
        k[N // 2] = 0.0
        dkd = np.fft.ifft(-(k**2) * np.fft.fft(kress[:, 0])).real
        csc2 = np.where(off, 2.0 * (np.pi / L) ** 2 / sin2, 0.0)
        self._E = c_log * csc2 + circulant(dkd)
        self._A_diag0 = (2.0 / 3.0) * self._c_dir * (np.pi / L) ** 2 - dkd[0]
        w = self._c_dir                          # (M f_x, M f_y, P f_x, P f_y, Q/2 f_x, Q/2 f_y) -> (u_x, u_y)
        self._combine = np.array([[w, 0.0], [0.0, w], [1.0, 0.0], [0.0, -1.0], [0.0, 2.0], [2.0, 0.0]])
        self._base_w = base / self._c_dir        # M / w = base / w - log|r|^2
        # workspace: N x N temporaries are reused (allocating them costs page faults)
        self._pairs = np.empty((N, 2))          # rank-2 factors of x_i - x_j etc. (see assemble)
        self._pairs_T = np.empty((2, 2 * N))
        self._tangent_pairs = np.empty((3, 2, N))
        # x, y of r = z_i - z_j (then their squares) while assembling, the three
        # outer products of the tangents in constraint_matrix: one buffer, 4 N x N in all
        self._scratch = np.empty((3, N, N))
        self._inv = np.empty((N, N))             # w / |r|^2
        self._assembled = None                   # blocks of the last assembled curve

    def _rank_two(self, left0, left1, right, out):
        """out_ij = left0_i right[0, j] + left1_i right[1, j] (``right`` of shape (2, m) or a
        stack (k, 2, m)).

        Outer products by BLAS: about twice as fast as numpy broadcasting at N ~ 100.
        """
        self._pairs[:, 0] = left0
        self._pairs[:, 1] = left1
        return np.matmul(self._pairs, right, out=out)

    @staticmethod
    def _diagonal(matrix: np.ndarray) -> np.ndarray:
        """A writable view of the diagonal of a C-contiguous square matrix."""
        return matrix.reshape(-1)[:: matrix.shape[0] + 1]

    def assemble(self, z: np.ndarray, tangent: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The kernel arrays (M / w, P, Q / 2) of G (module docstring) as a (3, N, N) array.

        ``out``, if given, is filled and returned.
        """
        N, w = self.N, self._c_dir
        x, y = self._scratch[0], self._scratch[1]
        right = self._pairs_T
        right[0] = 1.0
        right[1, :N], right[1, N:] = -z.real, -z.imag
        ones = right[0, :N]
        self._rank_two(z.real, ones, right[:, :N], out=x)          # x_i - x_j
        self._rank_two(z.imag, ones, right[:, N:], out=y)          # y_i - y_j
        blocks = np.empty((3, N, N)) if out is None else out
        M, P, Q = blocks
        np.multiply(x, y, out=Q)
        x *= x
        y *= y
        r2 = np.add(x, y, out=self._inv)
        self._diagonal(r2)[:] = 1.0
        np.subtract(x, y, out=P)
        np.log(r2, out=M)
        np.subtract(self._base_w, M, out=M)
        inv = np.divide(w, r2, out=r2)
        P *= inv                            # P = w Re(r / conj r)
        Q *= inv                            # Q / 2 = w Im(r / conj r) / 2
        t2 = tangent * tangent              # diagonal limit of r / conj r: s^2
        self._diagonal(P)[:] = w * t2.real
        self._diagonal(Q)[:] = (0.5 * w) * t2.imag
        self._assembled = blocks
        return blocks

    def constraint_matrix(self, tangent: np.ndarray, curvature: np.ndarray,
                          out: np.ndarray | None = None) -> np.ndarray:
        """A = B^T G B of the curve last passed to :meth:`assemble` (N x N, symmetric).

        B Lambda = d(Lambda s)/ds, so A = -sum_ab diag(t_a) T_ab diag(t_b) with
        T = D_s G D_s (module docstring). In closed form, with w = L / (8 pi N)
        the weight of the r / conj(r) part, E = -w csc2 + D_s K D_s and
        X = w Re(t_i t_j conj(r) / r),

            A_ij = -Re(t_i conj t_j) E_ij - (w / |r|^2) (4 X^2 / w^2 - 2)   (i != j),
            A_ii = -(7/6) w H_i^2 + (2/3) w (pi / L)^2 - (D_s K D_s)_ii.

        (2 X / w = (2/w) Re(t_i t_j) P + (4/w) Im(t_i t_j) Q/2: the factors go into
        the rank-2 outer products, so the off-diagonal part is eight passes.)
        It equals the spectral B^T G B up to the (spectral) error of derivatives
        of the smooth kernels: 1e-11 relative on a resolved shape, 1e-5 on the
        sharp tips of Delta = 2.3 at N = 128. :class:`hpcves.model.flow.MembraneFlow`
        therefore refines the tension against the exact constraint.
        """
        if self._assembled is None:
            raise RuntimeError("assemble a curve first")
        _, P, Q_half = self._assembled
        inv, w, N = self._inv, self._c_dir, self.N
        A = np.empty((N, N)) if out is None else out
        c, s = tangent.real, tangent.imag
        right = self._tangent_pairs
        right[0, 0], right[0, 1] = c, s                            # -> Re(t_i conj t_j)
        np.multiply(c, 2.0 / w, out=right[1, 0])                   # -> (2/w) Re(t_i t_j)
        np.multiply(s, -2.0 / w, out=right[1, 1])
        np.multiply(s, 4.0 / w, out=right[2, 0])                   # -> (4/w) Im(t_i t_j)
        np.multiply(c, 4.0 / w, out=right[2, 1])
        dot, real, imag = self._rank_two(c, s, right, out=self._scratch)
        np.multiply(dot, self._E, out=A)
        X = real
        X *= P
        imag *= Q_half
        X += imag                            # X = 2 X / w of the docstring
        np.square(X, out=X)
        np.subtract(2.0, X, out=X)
        X *= inv
        np.subtract(X, A, out=A)
        self._diagonal(A)[:] = self._A_diag0 - (7.0 / 6.0) * w * curvature**2
        return A

    def apply(self, blocks: np.ndarray, f: np.ndarray) -> np.ndarray:
        """Velocities u = G f (complex, shape (N,)) from a force density f (complex, shape (N,)).

        One product of the stacked arrays with (f_x, f_y) -- the interleaved real
        view of f, no copy -- gives M f_a, P f_a, Q/2 f_a; a second, (N x 6) by
        (6 x 2), combines them: u_x = M f_x + P f_x + Q f_y, u_y = M f_y - P f_y + Q f_x.
        """
        N = self.N
        f = np.ascontiguousarray(f, dtype=np.complex128)
        products = blocks.reshape(3 * N, N) @ f.view(np.float64).reshape(N, 2)
        by_node = products.reshape(3, N, 2).transpose(1, 0, 2).reshape(N, 6)
        return (by_node @ self._combine).view(np.complex128).ravel()

    def cartesian(self, blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(G_xx, G_xy, G_yy) from assembled kernel arrays."""
        M = self._c_dir * blocks[0]
        return M + blocks[1], 2.0 * blocks[2], M - blocks[1]

    def matrix(self, blocks: np.ndarray) -> np.ndarray:
        """The real symmetric 2N x 2N matrix G acting on (f_x, f_y) (for tests and analysis)."""
        Gxx, Gxy, Gyy = self.cartesian(blocks)
        return np.block([[Gxx, Gxy], [Gxy, Gyy]])
