"""The Stokes double-layer potential on a closed curve, for a viscosity contrast.

With inner and outer viscosities of ratio lambda = eta_in / eta_out the membrane
velocity u solves the second-kind equation (docs/numerics.md, "Viscosity contrast";
Pozrikidis, *Boundary Integral and Singularity Methods*, 1992, sec. 5.3;
Rahimian, Veerapaneni & Biros, J. Comput. Phys. 229, 2010, eq. 2.3)

    ((1 + lambda) / 2) u(x) - D[u](x) = u_inf(x) + S[f](x),

    D[u](x) = ((1 - lambda) / pi) oint (r . n) (r r^T) / |r|^4 u(y) ds(y),

r = x - y, n = n(y) the outward normal. On a rigid motion of the curve (a
translation, a rotation) D gives back -(1 - lambda) / 2 times it; at lambda = 1
it vanishes and the single-layer equation of equal viscosities is left.

The kernel is smooth on a smooth curve: with y = x + s t - (s^2 / 2) H n + O(s^3)
(t the unit tangent, H = d theta / ds the curvature, > 0 on a convex
counter-clockwise curve), (r . n)(r r^T) / |r|^4 -> -(H / 2) t t^T as y -> x.
The trapezoid rule on the nodes, with that limit on the diagonal, is then
spectrally accurate. With complex velocities u = u_x + i u_y,

    (r . n) (r r^T) / |r|^4 u = k r Re(r conj u),   k = Re(r conj n) / |r|^4,

so the operator is the real 2N x 2N matrix [[K_xx, K_xy], [K_xy, K_yy]] acting on
(u_x, u_y), K_ab = c w_j k r_a r_b, c = (1 - lambda) / pi, w_j the arclength
weights (L / N on hpcves's equal-arclength nodes).
"""
from __future__ import annotations

import numpy as np


def double_layer_matrix(z: np.ndarray, tangent: np.ndarray, curvature: np.ndarray, weights,
                        viscosity_ratio: float) -> np.ndarray:
    """The real 2N x 2N matrix of D (module docstring) at the nodes ``z`` of a closed curve.

    ``tangent``: unit tangents (complex, counter-clockwise); ``curvature``: H = d theta / ds;
    ``weights``: the arclength each node stands for (a number or N numbers; L / N on equally
    spaced arclength nodes). Zero at ``viscosity_ratio`` = 1.
    """
    z = np.asarray(z, dtype=complex)
    N = z.size
    scale = (1.0 - viscosity_ratio) / np.pi
    out = np.zeros((2 * N, 2 * N))
    if scale == 0.0:
        return out
    normal = -1j * np.asarray(tangent, dtype=complex)
    w = np.broadcast_to(np.asarray(weights, dtype=float), (N,))
    r = z[:, None] - z[None, :]
    r2 = np.abs(r) ** 2
    np.fill_diagonal(r2, 1.0)                     # the diagonal is its limit, set below
    k = (r.real * normal.real[None, :] + r.imag * normal.imag[None, :]) / (r2 * r2) * (scale * w)[None, :]
    xx, xy, yy = k * r.real * r.real, k * r.real * r.imag, k * r.imag * r.imag
    limit = -0.5 * np.asarray(curvature, dtype=float) * scale * w      # -(H / 2) t t^T, times c w
    t = np.asarray(tangent, dtype=complex)
    diagonal = np.arange(N)
    xx[diagonal, diagonal] = limit * t.real * t.real
    xy[diagonal, diagonal] = limit * t.real * t.imag
    yy[diagonal, diagonal] = limit * t.imag * t.imag
    out[:N, :N], out[:N, N:], out[N:, :N], out[N:, N:] = xx, xy, xy, yy
    return out


def apply_double_layer(matrix: np.ndarray, u: np.ndarray) -> np.ndarray:
    """D[u] (complex, at the nodes) from :func:`double_layer_matrix` and the complex velocity ``u``."""
    N = u.size
    v = matrix @ np.concatenate([u.real, u.imag])
    return v[:N] + 1j * v[N:]
