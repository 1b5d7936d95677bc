"""Right-preconditioned GMRES (Saad & Schultz, SIAM J. Sci. Stat. Comput. 7, 1986; Saad, *Iterative
Methods for Sparse Linear Systems*, 2nd ed., 2003, alg. 9.5), for the velocity of a viscosity contrast.

Solves K x = b by x = M^{-1} y, y minimising |b - K M^{-1} y| over the Krylov space of K M^{-1} and b:
with v_0 = b / |b|, the Arnoldi step w = K M^{-1} v_j is orthogonalised against v_0..v_j (modified
Gram-Schmidt) into v_{j+1}, the Hessenberg matrix H (H_ij = v_i . K M^{-1} v_j) is reduced by Givens
rotations as it grows, and |g_{j+1}| after the j-th rotation is the true residual |b - K x_j| (in exact
arithmetic; right preconditioning leaves the residual unpreconditioned). The caller gives one function
v -> (M^{-1} v, K M^{-1} v), which lets it share work between the two (flow.MembraneFlow).

Hand-written rather than scipy.sparse.linalg.gmres because the compiled engine runs the same
iteration inside numba (solver/compiled.py), and the two engines agree to round-off only when the
arithmetic is the same (docs/design.md).
"""
from __future__ import annotations

from typing import Callable

import numpy as np


def gmres(preconditioned: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], b: np.ndarray,
          tolerance: float, max_iterations: int) -> tuple[np.ndarray, float, int]:
    """(x, |b - K x| / |b|, iterations) with K x = b solved until the relative residual is at most
    ``tolerance`` or ``max_iterations`` are spent (the caller checks the residual it gets back).
    ``preconditioned(v)`` returns (M^{-1} v, K M^{-1} v). No restarts."""
    n = b.size
    beta = np.sqrt(b @ b)
    if beta == 0.0:
        return np.zeros(n), 0.0, 0
    basis = np.empty((max_iterations + 1, n))
    directions = np.empty((max_iterations, n))        # M^{-1} v_j, so that x needs no more M^{-1}
    H = np.zeros((max_iterations + 1, max_iterations))
    cosines, sines = np.empty(max_iterations), np.empty(max_iterations)
    g = np.zeros(max_iterations + 1)
    g[0] = beta
    basis[0] = b / beta
    m = 0
    for j in range(max_iterations):
        directions[j], w = preconditioned(basis[j])
        for i in range(j + 1):                          # modified Gram-Schmidt
            H[i, j] = w @ basis[i]
            w = w - H[i, j] * basis[i]
        H[j + 1, j] = np.sqrt(w @ w)
        if H[j + 1, j] != 0.0:
            basis[j + 1] = w / H[j + 1, j]
        for i in range(j):                              # the rotations so far, on the new column
            upper = cosines[i] * H[i, j] + sines[i] * H[i + 1, j]
            H[i + 1, j] = cosines[i] * H[i + 1, j] - sines[i] * H[i, j]
            H[i, j] = upper
        radius = np.hypot(H[j, j], H[j + 1, j])
        cosines[j], sines[j] = H[j, j] / radius, H[j + 1, j] / radius
        H[j, j], H[j + 1, j] = radius, 0.0
        g[j + 1] = -sines[j] * g[j]
        g[j] = cosines[j] * g[j]
        m = j + 1
        if abs(g[m]) <= tolerance * beta:            # H[m, j] = 0 (the space is invariant) lands here too
            break
    y = np.zeros(m)
    for i in range(m - 1, -1, -1):                      # back substitution, H upper triangular now
        y[i] = (g[i] - H[i, i + 1:m] @ y[i + 1:m]) / H[i, i]
    return y @ directions[:m], abs(g[m]) / beta, m
