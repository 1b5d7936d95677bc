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
    index = (np.arange(N)[:, None] - np.arange(N)[None, :]) % N
    return first[index]


class StokesSLP:
    """Single-layer Stokes operator on a curve of N material points and length L."""

    def __init__(self, N: int, length: float):
        self.N = N
        self.length = float(length)
        L = self.length
        c = 1.0 / (4.0 * np.pi)
        diff = np.arange(N)[:, None] - np.arange(N)[None, :]
        off = diff != 0
        log_sin2 = np.zeros((N, N))
        log_sin2[off] = np.log(4.0 * np.sin(np.pi * diff[off] / N) ** 2)
        # M = c [ -(L/(4 pi)) R  - (L/(2N)) (log|r|^2 - log 4 sin^2)  + (L/N)/2 ]
        #   = c_log * log|r|^2 + base       (diagonal: log|r|^2 := 0, limit folded into base)
        self._c_log = -c * L / (2.0 * N)
        base = -c * L / (4.0 * np.pi) * kress_weights(N) + c * L / (2.0 * N) * log_sin2 + c * L / (2.0 * N)
        base[~off] += self._c_log * 2.0 * np.log(L / (2.0 * np.pi))
        self._base = base
        self._c_dir = c * L / (2.0 * N)          # weight of the r/conj(r) conj(f) part
        self._diag = np.arange(N)
        # workspace: N x N temporaries are reused (allocating them costs page faults)
        self._r = np.empty((N, N), dtype=complex)
        self._r2 = np.empty((N, N))
        self._y2 = np.empty((N, N))
        self._M = np.empty((N, N))

    def assemble(self, z: np.ndarray, tangent: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The blocks (G_xx, G_xy, G_yy) of G as a (3, N, N) array.

        ``out``, if given, is filled and returned (e.g. an FFTW input buffer).
        """
        d = self._diag
        r = np.subtract(z[:, None], z[None, :], out=self._r)
        x, y = r.real, r.imag
        r2 = np.multiply(x, x, out=self._r2)
        y2 = np.multiply(y, y, out=self._y2)
        r2 += y2
        r2[d, d] = 1.0
        blocks = np.empty((3, self.N, self.N)) if out is None else out
        Gxx, Gxy, Gyy = blocks
        M = np.log(r2, out=self._M)
        M *= self._c_log
        M += self._base
        inv = np.divide(self._c_dir, r2, out=r2)
        P = np.multiply(x, x, out=Gxx)
        P -= y2
        P *= inv                            # P = Re(r / conj r) * w/2
        np.multiply(x, y, out=Gxy)
        Gxy *= inv
        Gxy *= 2.0                          # Q = Im(r / conj r) * w/2
        t2 = tangent * tangent              # diagonal limit of r / conj r: s^2
        P[d, d] = self._c_dir * t2.real
        Gxy[d, d] = self._c_dir * t2.imag
        np.subtract(M, P, out=Gyy)
        Gxx += M
        return blocks

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
