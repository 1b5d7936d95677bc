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

acting on (f_x, f_y). Only the three symmetric N x N blocks (G_xx, G_xy, G_yy)
are assembled, O(N^2) per shape; everything that depends only on N and L is
precomputed. One matrix product applies all three to any number of densities.

The tension system of :mod:`hpcves.flow` needs T_ab = D_s G_ab D_s, with D_s the
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
        self._c_log = -c * L / (2.0 * N)
        self._c_dir = c * L / (2.0 * N)          # weight of the r/conj(r) conj(f) part
        kress = -c * L / (4.0 * np.pi) * kress_weights(N)
        base = kress + self._c_dir * np.where(off, np.log(4.0 * sin2), 0.0) + self._c_dir
        base[~off] += self._c_log * 2.0 * np.log(L / (2.0 * np.pi))
        self._base = base
        # constraint operator (module docstring): D_s K D_s of the Kress part is
        # circulant with symbol -k^2 K_hat; the smooth log part contributes
        # -c_log (2 Re(t_i t_j / r^2) - csc2) off the diagonal.
        k = 2.0 * np.pi * np.fft.fftfreq(N, 1.0 / N) / L
        k[N // 2] = 0.0
        dkd = np.fft.ifft(-(k**2) * np.fft.fft(kress[:, 0])).real
        csc2 = np.where(off, 2.0 * (np.pi / L) ** 2 / sin2, 0.0)
        self._E = self._c_log * csc2 + circulant(dkd)
        self._A_diag0 = (2.0 / 3.0) * self._c_dir * (np.pi / L) ** 2 - dkd[0]
        self._diag = np.arange(N)
        # workspace: N x N temporaries are reused (allocating them costs page faults)
        self._pairs = np.empty((N, 2))          # rank-2 factors of x_i - x_j etc. (see assemble)
        self._pairs_T = np.empty((2, 3 * N))
        self._xy = np.empty((4, N, N))           # x, y, x^2, y^2 of r = z_i - z_j
        self._r2 = np.empty((N, N))
        self._M = np.empty((N, N))
        self._P = np.empty((N, N))
        self._outer = np.empty((N, 3 * N))
        self._work = np.empty((2, N, N))
        self._assembled = None                   # (blocks, inv) of the last assembled curve

    def _rank_two(self, left0, left1, right, out):
        """out_ij = left0_i right[0, j] + left1_i right[1, j] (``right`` of shape (2, m)).

        Outer products by BLAS: about twice as fast as numpy broadcasting at N ~ 100.
        """
        self._pairs[:, 0] = left0
        self._pairs[:, 1] = left1
        return np.matmul(self._pairs, right, out=out)

    def assemble(self, z: np.ndarray, tangent: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The blocks (G_xx, G_xy, G_yy) of G as a (3, N, N) array.

        ``out``, if given, is filled and returned.
        """
        d, N = self._diag, self.N
        x, y, x2, y2 = self._xy
        right = self._pairs_T[:, : 2 * N]
        right[0] = 1.0
        right[1, :N], right[1, N:] = -z.real, -z.imag
        ones = right[0, :N]
        self._rank_two(z.real, ones, right[:, :N], out=x)          # x_i - x_j
        self._rank_two(z.imag, ones, right[:, N:], out=y)          # y_i - y_j
        np.square(x, out=x2)
        np.square(y, out=y2)
        r2 = np.add(x2, y2, out=self._r2)
        r2[d, d] = 1.0
        blocks = np.empty((3, N, N)) if out is None else out
        Gxx, Gxy, Gyy = blocks
        M = np.log(r2, out=self._M)
        M *= self._c_log
        M += self._base
        inv = np.divide(self._c_dir, r2, out=r2)
        P = np.subtract(x2, y2, out=self._P)
        P *= inv                            # P = Re(r / conj r) * w/2
        np.multiply(x, y, out=Gxy)
        Gxy *= inv
        Gxy *= 2.0                          # Q = Im(r / conj r) * w/2
        t2 = tangent * tangent              # diagonal limit of r / conj r: s^2
        P[d, d] = self._c_dir * t2.real
        Gxy[d, d] = self._c_dir * t2.imag
        np.subtract(M, P, out=Gyy)
        np.add(M, P, out=Gxx)
        self._assembled = (blocks, inv)
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

        It equals the spectral B^T G B up to the (spectral) error of derivatives
        of the smooth kernels: 1e-11 relative on a resolved shape, 1e-5 on the
        sharp tips of Delta = 2.3 at N = 128. :class:`hpcves.flow.MembraneFlow`
        therefore refines the tension against the exact constraint.
        """
        if self._assembled is None:
            raise RuntimeError("assemble a curve first")
        (_, Q, _), inv = self._assembled
        P, w = self._P, self._c_dir
        N = self.N
        A = np.empty((N, N)) if out is None else out
        c, s = tangent.real, tangent.imag
        right = self._pairs_T
        right[0, :N], right[1, :N] = c, s            # -> Re(t_i conj t_j) = c_i c_j + s_i s_j
        right[0, N:2 * N], right[1, N:2 * N] = c, -s  # -> Re(t_i t_j) = c_i c_j - s_i s_j
        right[0, 2 * N:], right[1, 2 * N:] = s, c     # -> Im(t_i t_j) = c_i s_j + s_i c_j
        outer = self._rank_two(c, s, right, out=self._outer)
        dot, real, imag = outer[:, :N], outer[:, N:2 * N], outer[:, 2 * N:]
        np.multiply(dot, self._E, out=A)
        X, Y = self._work
        np.multiply(real, P, out=X)
        np.multiply(imag, Q, out=Y)
        X += Y                               # X = Re(t_i t_j) P + Im(t_i t_j) Q
        np.square(X, out=X)
        X *= -4.0 / w**2
        X += 2.0
        X *= inv
        np.subtract(X, A, out=A)
        d = self._diag
        A[d, d] = self._A_diag0 - (7.0 / 6.0) * w * curvature**2
        return A

    @staticmethod
    def apply(blocks: np.ndarray, f: np.ndarray) -> np.ndarray:
        """Velocities (complex) from force densities f: one density (N,) or several (N, k)."""
        N = blocks.shape[1]
        single = f.ndim == 1
        f2 = f[:, None] if single else f
        k = f2.shape[1]
        products = blocks.reshape(3 * N, N) @ np.concatenate([f2.real, f2.imag], axis=1)
        xx, xy, yy = products[:N], products[N:2 * N], products[2 * N:]
        u = (xx[:, :k] + xy[:, k:]) + 1j * (xy[:, :k] + yy[:, k:])
        return u[:, 0] if single else u

    def matrix(self, blocks: np.ndarray) -> np.ndarray:
        """The real symmetric 2N x 2N matrix G acting on (f_x, f_y) (for tests and analysis)."""
        Gxx, Gxy, Gyy = blocks
        return np.block([[Gxx, Gxy], [Gxy, Gyy]])
