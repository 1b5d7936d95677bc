"""The right-hand side, the SBDF2 step, a sample and the health check of :mod:`hpcves.solver.timestepping`
and :mod:`hpcves.run.diagnostics`, compiled (numba).

The same equations as the numpy path, in the same order, fused into three calls a step:
:func:`shape_rates` and :func:`flow_rates` (the right-hand side: the shape, the bending force, the
Stokes flow with its tension and refinement, theta_t, mu and psi_t -- geometry.shape_from_angle,
forces, quadrature.StokesSLP, flow.MembraneFlow.solve, phasefield.chemical_potential, bending's
saturating law) and :func:`sbdf2` (the theta step and its projection onto closed curves of the
initial area, the phase step in the pattern frame with its linearly implicit Woodbury solve, or the
stabilised Euler step where that is not applicable, and the error estimate: Solver._sbdf2 and what
it calls); and one call a sample (:func:`sample_values`: diagnostics.sample) and a step
(:func:`soundness`: diagnostics.health's per-step part). Their docstrings are there; this module
only says where it differs:

* transforms are pocketfft's (numpy.fft inside numba, through rocket-fft), the exponentials,
  logarithms and erfc libm's, and reductions summed in order: results differ from the numpy
  path by round-off (1e-15 relative a step), never by more;
* the logarithm of the single-layer kernel is numpy's (vectorised; libm's scalar one costs 6x
  more), so the rates are two calls around it;
* the 3 x 3 Newton system of the area projection is solved by Gaussian elimination with partial
  pivoting (LAPACK's dgesv in the numpy path), the tension's triangular solves by loops, the
  interpolant of a sample by powers of e^{2 pi i alpha};
* with a viscosity contrast the velocity's GMRES (numerics/krylov.py) is :func:`_contrast_flow`, the same
  iteration, with the double layer's matrix and the Krylov vectors in the solver's workspace;
* errors come back as numbers (the stretching the tension leaves, GMRES's residual) or, from LAPACK (the tension's
  Cholesky factorisation, the phase step's capacitance system), as numpy's LinAlgError, which the
  caller turns into the numpy path's exceptions.

Why compiled (docs/design.md, "The compiled step"): at N = 64 three quarters of a numpy step was
the fixed cost of ~300 small array operations; fused, a step costs about its arithmetic.
Functions are compiled on first use and cached on disk (numba's ``cache=True``), so a process
pays the compilation once per machine (~20 s) and ~0.3 s to load it after.
"""
from __future__ import annotations

import math

import numba
import numpy as np
import rocket_fft  # noqa: F401  (registers numpy.fft for numba)

from hpcves.model import bending, geometry, phasefield
from hpcves.model.flow import MembraneFlow

jit = numba.njit(cache=True, nogil=True, error_model="numpy")


#: the numpy path's constants, the same objects (frozen into the kernels when they compile)
REFINEMENT_TOLERANCE = MembraneFlow.REFINEMENT_TOLERANCE
MAX_REFINEMENTS = MembraneFlow.MAX_REFINEMENTS
GMRES_TOLERANCE, MAX_ITERATIONS = MembraneFlow.GMRES_TOLERANCE, MembraneFlow.MAX_ITERATIONS
SHARPNESS, SATURATION = bending.SHARPNESS, bending.SATURATION
SPINODAL_HALF_WIDTH, PLAUSIBLE = float(phasefield.SPINODAL_HALF_WIDTH), phasefield.PLAUSIBLE


# ---------------------------------------------------------------- spectral calculus (spectral.py)
@jit
def _multiply(f, symbol, n):
    """irfft(symbol rfft(f))."""
    return np.fft.irfft(symbol * np.fft.rfft(f), n)


@jit
def _multiply_complex(f, symbol):
    return np.fft.ifft(symbol * np.fft.fft(f))


@jit
def _antiderivative(w, inv_ikc, mean):
    """spectral.antiderivative_complex: mode 0 set to mean N."""
    spectrum = inv_ikc * np.fft.fft(w)
    spectrum[0] = mean * w.size
    return np.fft.ifft(spectrum)


@jit
def _largest_magnitude(x):
    best = 0.0
    for value in x:
        size = abs(value)
        if size > best or size != size:
            best = size
            if size != size:
                return size
    return best


@jit
def _shift_symbol(a, im2pi, N):
    symbol = np.exp(-a * im2pi)
    symbol[-1] = math.cos(math.pi * N * a)
    return symbol


# ---------------------------------------------------------------- bending law (bending.py)
@jit
def _law(p, saturating, width):
    """(s, s', s'') of the bending law at one psi: B = B1 + (B2 - B1) s(psi)."""
    if not saturating or (p >= 0.0 and p <= 1.0):
        return p, 1.0, 0.0
    above = p > 1.0
    x = (p - 1.0) / width if above else -p / width
    sign = 1.0 if above else -1.0
    log_x = math.log(x)
    a = SHARPNESS
    G = 0.5 * math.exp(log_x) * math.erfc(a * log_x) + 0.5 * SATURATION * math.erfc(0.5 / a - a * log_x)
    s = (1.0 if above else 0.0) + sign * width * G
    prime = 0.5 * math.erfc(a * log_x)
    second = sign * (-a / math.sqrt(math.pi) * math.exp(-(a * log_x) ** 2 - log_x)) / width
    return s, prime, second


# ---------------------------------------------------------------- single-layer potential (quadrature.py)
@jit
def _squared_distances(z, r2):
    """r2_ij = |z_i - z_j|^2 off the diagonal, 1 on it (numpy takes its logarithm: vectorised there)."""
    N = z.size
    for i in range(N):
        xi, yi = z[i].real, z[i].imag
        row = r2[i]
        for j in range(N):
            dx = xi - z[j].real
            dy = yi - z[j].imag
            row[j] = dx * dx + dy * dy
        row[i] = 1.0
    return r2


@jit
def _assemble(z, tangent, log_r2, base_w, w, blocks):
    """(M / w, P, Q / 2) of StokesSLP.assemble into ``blocks`` given log|r|^2 (0 on the diagonal);
    returns w / |r|^2 (w on the diagonal)."""
    N = z.size
    inv = np.empty((N, N))
    M, P, Q = blocks[0], blocks[1], blocks[2]
    for i in range(N):
        xi, yi = z[i].real, z[i].imag
        for j in range(N):
            dx = xi - z[j].real
            dy = yi - z[j].imag
            xx, yy = dx * dx, dy * dy
            ir = w / (xx + yy)
            M[i, j] = base_w[i, j] - log_r2[i, j]
            P[i, j] = (xx - yy) * ir
            Q[i, j] = (dx * dy) * ir
            inv[i, j] = ir
        t2 = tangent[i] * tangent[i]
        P[i, i] = w * t2.real
        Q[i, i] = (0.5 * w) * t2.imag
        inv[i, i] = w
    return inv


@jit
def _apply(blocks, f, w):
    """u = G f (StokesSLP.apply): M f_a, P f_a, Q/2 f_a by one matrix product, then combined."""
    N = f.size
    density = np.empty((N, 2))
    for j in range(N):
        density[j, 0] = f[j].real
        density[j, 1] = f[j].imag
    products = np.dot(blocks.reshape(3 * N, N), density)
    u = np.empty(N, dtype=np.complex128)
    for i in range(N):
        ux = w * products[i, 0] + products[N + i, 0] + 2.0 * products[2 * N + i, 1]
        uy = w * products[i, 1] - products[N + i, 1] + 2.0 * products[2 * N + i, 0]
        u[i] = complex(ux, uy)
    return u


@jit
def _constraint_matrix(tangent, curvature, blocks, inv, E, w, A_diag0):
    """A = B^T G B in closed form (StokesSLP.constraint_matrix)."""
    N = tangent.size
    A = np.empty((N, N))
    P, Q_half = blocks[1], blocks[2]
    c = tangent.real.copy()
    s = tangent.imag.copy()
    for i in range(N):
        ci, si = c[i], s[i]
        for j in range(N):
            X = (2.0 / w) * (ci * c[j] - si * s[j]) * P[i, j] + (4.0 / w) * (si * c[j] + ci * s[j]) * Q_half[i, j]
            A[i, j] = (2.0 - X * X) * inv[i, j] - (ci * c[j] + si * s[j]) * E[i, j]
        A[i, i] = A_diag0 - (7.0 / 6.0) * w * curvature[i] ** 2
    return A


@jit
def _cholesky_solve(L, b):
    """x with L L^T x = b (L lower): L y = b by row dot products, then L^T x = y by row axpys."""
    N = b.size
    y = np.empty(N)
    for i in range(N):
        total = b[i]
        row = L[i, :i]
        for m in range(row.size):
            total -= row[m] * y[m]
        y[i] = total / L[i, i]
    for i in range(N - 1, -1, -1):
        y[i] /= L[i, i]
        value = y[i]
        row, target = L[i, :i], y[:i]
        for m in range(row.size):
            target[m] -= value * row[m]
    return y


@jit
def _stretching(tangent, u, ikc):
    """s . du/ds."""
    du = _multiply_complex(u, ikc)
    return tangent.real * du.real + tangent.imag * du.imag


@jit
def _tension_force(tension, tangent, ikc):
    return _multiply_complex(tension * tangent, ikc)


@jit
def _refined_flow(tangent, blocks, L, u0, rhs, w, ikc):
    """The tension by the Cholesky factor L of A and its refinement (flow.MembraneFlow.solve): (the
    stretching left, the one the tension cancels, u, tension)."""
    tension = _cholesky_solve(L, rhs)
    u = u0 + _apply(blocks, _tension_force(tension, tangent, ikc), w)
    scale = _largest_magnitude(rhs)
    previous = np.inf
    size = 0.0
    for refinements in range(MAX_REFINEMENTS + 1):
        residual = _stretching(tangent, u, ikc)
        size = _largest_magnitude(residual)
        if size <= REFINEMENT_TOLERANCE * scale or size > 0.5 * previous or refinements == MAX_REFINEMENTS:
            break
        previous = size
        correction = _cholesky_solve(L, residual)
        tension += correction
        u += _apply(blocks, _tension_force(correction, tangent, ikc), w)
    return size, scale, u, tension


@jit
def _double_layer(z, tangent, curvature, inv, w, weight, viscosity_ratio, out):
    """double_layer.double_layer_matrix on nodes of equal ``weight`` (L / N) into ``out``, from the
    w / |r|^2 of :func:`_assemble` (``inv``), which spares its divisions."""
    N = z.size
    scale = (1.0 - viscosity_ratio) / math.pi * weight / (w * w)    # c weight / |r|^4 = scale (w / |r|^2)^2
    nx, ny = tangent.imag.copy(), -tangent.real                  # n = -i t
    for i in range(N):
        xi, yi = z[i].real, z[i].imag
        top, bottom, row = out[i], out[N + i], inv[i]
        for j in range(N):
            dx = xi - z[j].real
            dy = yi - z[j].imag
            k = (dx * nx[j] + dy * ny[j]) * scale * (row[j] * row[j])
            xy = k * dx * dy
            top[j], top[N + j], bottom[j], bottom[N + j] = k * (dx * dx), xy, xy, k * (dy * dy)
        tx, ty = tangent[i].real, tangent[i].imag
        k = -0.5 * curvature[i] * (1.0 - viscosity_ratio) / math.pi * weight     # the limit -(H / 2) t t^T
        top[i], top[N + i], bottom[i], bottom[N + i] = k * tx * tx, k * tx * ty, k * tx * ty, k * ty * ty


@jit
def _rigid_motions(z):
    """flow.rigid_motions."""
    N = z.size
    out = np.zeros((2 * N, 3))
    mean = z.sum() / N
    total = 0.0
    for i in range(N):
        out[i, 0] = out[N + i, 1] = 1.0 / math.sqrt(N)
        arm = z[i] - mean
        out[i, 2], out[N + i, 2] = -arm.imag, arm.real
        total += arm.imag * arm.imag + arm.real * arm.real
    out[:, 2] /= math.sqrt(total)
    return out


@jit
def _contrast_flow(z, tangent, blocks, L, u0, w, ikc, viscosity_ratio, krylov):
    """u and the tension of a viscosity contrast by right-preconditioned GMRES
    (flow.MembraneFlow._solve_with_contrast; numerics/krylov.gmres, the same iteration): (the stretching
    left, the one the tension cancels, u, tension); a stretching of inf when GMRES did not converge."""
    N = z.size
    c = 0.5 * (1.0 + viscosity_ratio)
    D, basis, directions = krylov               # D assembled by flow_rates (_double_layer)
    n, m_max = 3 * N, MAX_ITERATIONS
    b = np.empty(n)
    for j in range(N):
        b[j], b[N + j], b[2 * N + j] = u0[j].real, u0[j].imag, 0.0
    beta = math.sqrt(np.dot(b, b))
    H = np.zeros((m_max + 1, m_max))
    cosines, sines, g = np.empty(m_max), np.empty(m_max), np.zeros(m_max + 1)
    g[0] = beta
    basis[0] = b / beta
    rigid = _rigid_motions(z)
    r1 = np.empty(N, dtype=np.complex128)
    image = np.empty(n)
    m = 0
    v, flat = np.empty(2 * N), np.empty(2 * N)         # contiguous, for BLAS (numba's dot of slices is a loop)
    for j in range(m_max):
        # M^{-1} basis[j] and K M^{-1} basis[j]
        v[:] = basis[j, :2 * N]
        v += (c - 1.0) * np.dot(rigid, np.dot(v, rigid))
        for i in range(N):
            r1[i] = complex(v[i], v[N + i])
        tension = _cholesky_solve(L, _stretching(tangent, r1, ikc) - c * basis[j, 2 * N:])
        u = (r1 + _apply(blocks, _tension_force(tension, tangent, ikc), w)) / c
        d = directions[j]
        for i in range(N):
            flat[i], flat[N + i] = u[i].real, u[i].imag
            d[i], d[N + i], d[2 * N + i] = u[i].real, u[i].imag, tension[i]
        image[:2 * N] = v - np.dot(D, flat)
        image[2 * N:] = _stretching(tangent, u, ikc)
        for i in range(j + 1):                          # modified Gram-Schmidt
            h = np.dot(image, basis[i])
            H[i, j] = h
            image -= h * basis[i]
        H[j + 1, j] = math.sqrt(np.dot(image, image))
        if H[j + 1, j] != 0.0:
            basis[j + 1] = image / H[j + 1, j]
        for i in range(j):
            upper = cosines[i] * H[i, j] + sines[i] * H[i + 1, j]
            H[i + 1, j] = cosines[i] * H[i + 1, j] - sines[i] * H[i, j]
            H[i, j] = upper
        radius = math.hypot(H[j, j], H[j + 1, j])
        cosines[j], sines[j] = H[j, j] / radius, H[j + 1, j] / radius
        H[j, j], H[j + 1, j] = radius, 0.0
        g[j + 1] = -sines[j] * g[j]
        g[j] = cosines[j] * g[j]
        m = j + 1
        if abs(g[m]) <= GMRES_TOLERANCE * beta:
            break
    y = np.zeros(m)
    for i in range(m - 1, -1, -1):
        total = g[i]
        for k in range(i + 1, m):
            total -= H[i, k] * y[k]
        y[i] = total / H[i, i]
    x = np.zeros(n)
    for i in range(m):                                  # sum_i y_i M^{-1} v_i
        x += y[i] * directions[i]
    u = np.empty(N, dtype=np.complex128)
    for i in range(N):
        u[i] = complex(x[i], x[N + i])
    scale = _largest_magnitude(_stretching(tangent, u0, ikc)) / c
    size = _largest_magnitude(_stretching(tangent, u, ikc))
    return size, scale, u, x[2 * N:].copy(), abs(g[m]) / beta


# ---------------------------------------------------------------- rates (Solver._rates_on_nodes)
@jit
def shape_rates(theta_tilde, psi, center, homogeneous, ops, phys):
    """The first part of F at one level: the shape, psi's derivatives, the bending force and the squared
    distances |z_i - z_j|^2 whose logarithm the single-layer kernel needs. ``ops``: the grid's operators
    (Solver._operators); ``phys``: (length, B1, B2, saturating, width, shear_rate, a0, eps, mobility,
    viscosity_ratio).
    Returns (psi_hat, psi_s, psi_ss, z, tangent, curvature, B'(psi), f_b, r2)."""
    (circle, ik, k2, ikc, inv_ikc, base_w, E, w, A_diag0, mobility_k2, blocks, krylov) = ops
    length, B1, B2, saturating, width, shear_rate, a0, eps, mobility, viscosity_ratio = phys
    N = theta_tilde.size
    # shape (geometry.shape_from_angle)
    theta = circle + theta_tilde
    tangent = np.exp(1j * theta)
    z = _antiderivative(tangent, inv_ikc, center)
    curvature = 2.0 * math.pi / length + _multiply(theta_tilde, ik, N)
    # phase derivatives and the bending law
    B = np.empty(N)
    dB = np.empty(N)
    if homogeneous:
        psi_hat = np.zeros(N // 2 + 1, dtype=np.complex128)
        psi_s = np.zeros(N)
        psi_ss = np.zeros(N)
    else:
        psi_hat = np.fft.rfft(psi)
        psi_s = np.fft.irfft(ik * psi_hat, N)
        psi_ss = np.fft.irfft(k2 * psi_hat, N)
    for j in range(N):
        s, prime, _ = _law(psi[j], saturating, width)
        B[j] = B1 + (B2 - B1) * s
        dB[j] = (B2 - B1) * prime
    # bending force (forces.bending_force)
    BH = B * curvature
    normal_part = _multiply(BH, k2, N) + 0.5 * (BH * curvature) * curvature
    f_b = np.empty(N, dtype=np.complex128)
    for j in range(N):
        f_b[j] = complex(curvature[j] * curvature[j] * (0.5 * dB[j] * psi_s[j]), -normal_part[j]) * tangent[j]
    r2 = _squared_distances(z, np.empty((N, N)))
    return psi_hat, psi_s, psi_ss, z, tangent, curvature, dB, f_b, r2


@jit
def flow_rates(theta_tilde, psi, center, homogeneous, ops, phys, log_r2, psi_hat, psi_s, psi_ss, z, tangent,
               curvature, dB, f_b):
    """The rest of F at one level, given log|r|^2 and what :func:`shape_rates` gave. Returns (the
    stretching left after refining, the one the tension cancels -- their ratio the caller checks as
    flow.MembraneFlow.solve does --, GMRES's relative residual with a viscosity contrast (0 without),
    theta_t, psi_t, center rate, V, velocity, tension_eff, mu)."""
    (circle, ik, k2, ikc, inv_ikc, base_w, E, w, A_diag0, mobility_k2, blocks, krylov) = ops
    length, B1, B2, saturating, width, shear_rate, a0, eps, mobility, viscosity_ratio = phys
    N = theta_tilde.size
    # flow and tension (flow.MembraneFlow.solve)
    inv = _assemble(z, tangent, log_r2, base_w, w, blocks)
    if viscosity_ratio != 1.0:
        _double_layer(z, tangent, curvature, inv, w, length / N, viscosity_ratio, krylov[0])
    u0 = _apply(blocks, f_b, w)
    u0 += shear_rate * z.imag
    rhs = _stretching(tangent, u0, ikc)
    A = _constraint_matrix(tangent, curvature, blocks, inv, E, w, A_diag0)
    empty = np.empty(0)
    A = np.linalg.cholesky(A)            # LAPACK's dpotrf (LinAlgError: not positive definite)
    if viscosity_ratio != 1.0:
        size, scale, u, tension, residual = _contrast_flow(z, tangent, blocks, A, u0, w, ikc, viscosity_ratio,
                                                           krylov)
    else:
        size, scale, u, tension = _refined_flow(tangent, blocks, A, u0, rhs, w, ikc)
        residual = 0.0

    # theta_t = -n . d(u - V s)/ds
    V = 0.0
    for j in range(N):
        V += tangent[j].real * u[j].real + tangent[j].imag * u[j].imag
    V /= N
    node_velocity_s = _multiply_complex(u - V * tangent, ikc)
    theta_t = tangent.real * node_velocity_s.imag - tangent.imag * node_velocity_s.real
    center_rate = u.sum() / N
    if homogeneous:
        return size, scale, residual, theta_t, np.zeros(N), center_rate, V, u, tension, empty
    # chemical potential (phasefield.chemical_potential) and psi_t = nu mu_ss
    mu = np.empty(N)
    for j in range(N):
        p = psi[j] - 0.5
        mu[j] = ((p * p - 0.25) * p * (a0 / eps) + (0.5 * dB[j]) * (curvature[j] * curvature[j])
                 - (a0 * eps) * psi_ss[j])
    psi_t = _multiply(mu, mobility_k2, N)
    return size, scale, residual, theta_t, psi_t, center_rate, V, u, tension, mu


# ---------------------------------------------------------------- projection (geometry.project_closed)
@jit
def _closure_step(theta, e):
    n = theta.size
    c, s = e.real, e.imag
    defect = e.sum() / n
    ss = cs = cc = 0.0
    for j in range(n):
        ss += s[j] * s[j]
        cs += c[j] * s[j]
        cc += c[j] * c[j]
    ss, cs, cc = ss / n, cs / n, cc / n
    det = ss * cc - cs * cs
    p = -(cc * defect.real + cs * defect.imag) / det
    q = -(cs * defect.real + ss * defect.imag) / det
    return theta + (q * c - p * s)


@jit
def _area(e, z, length):
    N = e.size
    total = 0.0
    for j in range(N):
        total += e[j].real * z[j].imag - e[j].imag * z[j].real
    return -0.5 * length * total / N


@jit
def _solve3(a, b):
    """x with a x = b (3 x 3, Gaussian elimination with partial pivoting); ok False if singular."""
    a = a.copy()
    b = b.copy()
    for col in range(3):
        pivot = col
        for row in range(col + 1, 3):
            if abs(a[row, col]) > abs(a[pivot, col]):
                pivot = row
        if a[pivot, col] == 0.0:
            return b, False
        if pivot != col:
            for k in range(3):
                a[col, k], a[pivot, k] = a[pivot, k], a[col, k]
            b[col], b[pivot] = b[pivot], b[col]
        for row in range(col + 1, 3):
            factor = a[row, col] / a[col, col]
            for k in range(col, 3):
                a[row, k] -= factor * a[col, k]
            b[row] -= factor * b[col]
    x = np.empty(3)
    for row in range(2, -1, -1):
        s = b[row]
        for k in range(row + 1, 3):
            s -= a[row, k] * x[k]
        x[row] = s / a[row, row]
    return x, True


@jit
def _project_closed(theta, circle, inv_ikc, length, area):
    """(theta, area before) on closed curves of ``area`` (NaN: closure only; area before NaN)."""
    N = theta.size
    e = np.exp(1j * theta)
    if area != area:
        return _closure_step(theta, e), np.nan
    rows = np.empty((4, N))
    for j in range(N):
        rows[0, j] = theta[j] - circle[j]
    rows[0] -= rows[0].sum() / N
    z = _antiderivative(e, inv_ikc, 0.0)
    A = before = _area(e, z, length)
    for j in range(N):
        rows[1, j] = -e[j].imag
        rows[2, j] = e[j].real
        rows[3, j] = (e[j].real * z[j].real + e[j].imag * z[j].imag) * (length / N)
    jacobian = np.dot(rows[1:], rows[:3].T)
    if abs(jacobian[2, 0]) <= 1e-12 * area:
        return _closure_step(theta, e), before
    first = -1.0
    for _ in range(6):
        defect = e.sum()
        if abs(A - area) <= 1e-13 * area and abs(defect) <= 1e-15 * N:
            break
        lam, ok = _solve3(jacobian, np.array([-defect.real, -defect.imag, area - A]))
        if not ok:
            return _closure_step(theta, e), before
        correction = lam[0] * rows[0] + lam[1] * rows[1] + lam[2] * rows[2]
        theta = theta + correction
        size = _largest_magnitude(correction)
        if first < 0.0:
            first = size
        if size * first <= geometry.PROJECTION_REMAINDER:
            break
        e = np.exp(1j * theta)
        z = _antiderivative(e, inv_ikc, 0.0)
        A = _area(e, z, length)
    return theta, before


# ---------------------------------------------------------------- phase step (phasefield.py, Solver._sbdf2_phase)
@jit
def _applicable(psi, run_points):
    """phasefield.LinearizedImplicit.applicable."""
    N = psi.size
    largest = 0.0
    for value in psi:
        d = abs(value - 0.5)
        if not d <= largest:
            largest = d
            if d != d:
                return False
    if not largest <= 0.55:
        return False
    if run_points > N:
        return True
    run = 0
    for j in range(N + run_points - 1):
        if abs(psi[j % N] - 0.5) < SPINODAL_HALF_WIDTH:
            run += 1
            if run >= run_points:
                return False
        else:
            run = 0
    return True


@jit
def _plausible(psi):
    for value in psi:
        if not (PLAUSIBLE[0] <= value and value <= PLAUSIBLE[1]):
            return False
    return True


@jit
def _displacement(f_hat, g_hat, N, im2pi, m2pi, reach):
    """spectral.Spectral.displacement with window reach / N, of the spectra f_hat, g_hat."""
    q = f_hat * np.conj(g_hat)
    q[0] = 0.0
    q[-1] = 0.0
    R = np.fft.irfft(q, N)
    best_lag = -reach
    best_value = -np.inf
    for lag in range(-reach, reach + 1):
        value = R[lag % N]
        if value > best_value:
            best_value, best_lag = value, lag
    a = a_grid = best_lag / N
    j = best_lag % N
    before, peak, after = R[j - 1], R[j], R[(j + 1) % N]
    if peak == 0.0:
        variation = False
        for value in q:
            if value != 0.0:
                variation = True
        if not variation:
            return 0.0
    if before - 2.0 * peak + after < 0.0:
        a += 0.5 * (before - after) / (before - 2.0 * peak + after) / N
    for _ in range(20):
        wave = q * np.exp(a * im2pi)
        slope = 0.0
        curvature = 0.0
        for m in range(wave.size):
            slope += m2pi[m] * wave[m].imag
            curvature += m2pi[m] * m2pi[m] * wave[m].real
        if curvature <= 0.0:
            break
        step = slope / curvature
        a -= step
        if abs(step) < 1e-5:
            break
    if not abs(a - a_grid) <= 1.0 / N:
        return a_grid
    return a


@jit
def _solve_spectral(psi_star, psi_star_hat, c, explicit_hat, advection, bending, ch):
    """phasefield.LinearizedImplicit.solve_spectral; ``bending`` (B'' H^2 / 2) of length 0 if none."""
    bulk, ik, c2_k2, bending_scale, cutoff, run_points = ch
    N = psi_star.size
    e = 3.0 * psi_star * (psi_star - 1.0)
    if bending.size:
        e += bending_scale * bending
    count = 0
    for j in range(N):
        if abs(e[j]) > cutoff:
            count += 1
    P = np.empty(count, dtype=np.int64)
    count = 0
    for j in range(N):
        if abs(e[j]) > cutoff:
            P[count] = j
            count += 1
    rhs_hat = explicit_hat + bulk * psi_star_hat
    kappa = (c + bulk) + advection * ik
    if count == 0:
        return np.fft.irfft(rhs_hat / kappa, N)
    w = np.zeros(N)
    for a in range(count):
        w[P[a]] = e[P[a]] * psi_star[P[a]]
    rhs_hat -= c2_k2 * np.fft.rfft(w)
    z = np.fft.irfft(rhs_hat / kappa, N)
    Q_symbol = c2_k2 / kappa
    minus_q = np.fft.irfft(-Q_symbol, N)
    capacitance = np.empty((count, count))
    right = np.empty(count)
    for a in range(count):
        for b in range(count):
            capacitance[a, b] = minus_q[(P[a] - P[b]) % N]
        capacitance[a, a] += 1.0 / e[P[a]]
        right[a] = z[P[a]]
    y = np.linalg.solve(capacitance, right)          # LAPACK's dgesv (LinAlgError: singular)
    w[:] = 0.0
    for a in range(count):
        w[P[a]] = y[a]
    return z + np.fft.irfft(Q_symbol * np.fft.rfft(w), N)


@jit
def _stabilized_euler(psi, rate, dt, advection, lam_psi, ik, N):
    damping = 1.0 + dt * (lam_psi + advection * ik)
    return np.fft.irfft(np.fft.rfft(psi + dt * rate) / damping + np.fft.rfft(psi) * (dt * lam_psi / damping), N)


# ---------------------------------------------------------------- the step (Solver._sbdf2)
@jit
def sbdf2(theta, prev_theta, prev2_theta, rate_theta, prev_rate_theta,
          psi, prev_psi, prev2_psi, rate_psi, prev_rate_psi, psi_hat, curvature,
          shift_rate, prev_rate_shift, k, w, dt_prev, dt_prev2, homogeneous, area0, jacobian_bending, ops, step_ops,
          ch, phys):
    """One variable-step SBDF2 step of theta_tilde and psi (Solver._sbdf2 and _sbdf2_phase).
    ``prev2_*`` of length 0 before step 2. Returns (theta, area before, theta error, theta scale, psi,
    psi error, psi scale, order)."""
    circle, ik = ops[0], ops[1]
    inv_ikc = ops[4]
    lam_theta, resolved, lam_psi, im2pi, m2pi, reach = step_ops
    length, B1, B2, saturating, width = phys[0], phys[1], phys[2], phys[3], phys[4]
    N = theta.size
    implicit, current, previous = (1.0 + 2.0 * w) / (1.0 + w), 1.0 + w, w * w / (1.0 + w)
    # theta: SBDF2 with the implicit bending symbol, projected
    explicit = (current * theta - previous * prev_theta) / k + current * rate_theta - w * prev_rate_theta
    theta_star = current * theta - w * prev_theta
    theta_hat = (np.fft.rfft(explicit) + lam_theta * np.fft.rfft(theta_star)) * (1.0 / (implicit / k + lam_theta))
    full = np.fft.irfft(resolved * theta_hat, N) + circle
    full, before = _project_closed(full, circle, inv_ikc, length, area0)
    new_theta = full - circle
    quadratic = prev2_theta.size > 0
    l0 = l1 = l2 = 0.0
    if quadratic:
        k1, k2_ = dt_prev, dt_prev2
        l0 = (k + k1) * (k + k1 + k2_) / (k1 * (k1 + k2_))
        l1 = -k * (k + k1 + k2_) / (k1 * k2_)
        l2 = k * (k + k1) / (k2_ * (k1 + k2_))
        theta_error = new_theta - (l0 * theta + l1 * prev_theta + l2 * prev2_theta)
    else:
        theta_error = new_theta - theta_star
    theta_scale = max(_largest_magnitude(new_theta), _largest_magnitude(theta))
    order = 3 if quadratic else 2
    if homogeneous:
        return new_theta, before, theta_error, theta_scale, psi, np.empty(0), 0.0, order
    # psi: SBDF2 in the pattern frame
    prev_hat = np.fft.rfft(prev_psi)
    moved = _displacement(psi_hat, prev_hat, N, im2pi, m2pi, reach)
    W = length * moved / dt_prev
    if w == 1.0:
        to_n = _shift_symbol(moved, im2pi, N)
        to_prev = to_n * to_n
        to_prev[-1] = math.cos(2.0 * math.pi * N * moved)
    else:
        to_n, to_prev = _shift_symbol(w * moved, im2pi, N), _shift_symbol((1.0 + w) * moved, im2pi, N)
    star_hat = current * (psi_hat * to_n) - w * (prev_hat * to_prev)
    psi_star = np.fft.irfft(star_hat, N)
    V_star = length * (current * shift_rate - w * prev_rate_shift)
    run_points = ch[5]
    new_psi = psi_star
    fell_back = True
    if _applicable(psi_star, run_points) and _applicable(psi, run_points) and _applicable(prev_psi, run_points):
        explicit_hat = (((current / k) * psi_hat + current * np.fft.rfft(rate_psi)) * to_n
                        - ((previous / k) * prev_hat + w * np.fft.rfft(prev_rate_psi)) * to_prev)
        bending = np.empty(0)
        if saturating and jacobian_bending:
            outside = False
            for value in psi_star:
                if not (value >= 0.0 and value <= 1.0):
                    outside = True
            if outside:
                bending = np.empty(N)
                for j in range(N):
                    _, _, second = _law(psi_star[j], saturating, width)
                    bending[j] = 0.5 * ((B2 - B1) * second) * curvature[j] * curvature[j]
        new_psi = _solve_spectral(psi_star, star_hat, implicit / k, explicit_hat, V_star - W, bending, ch)
        if _plausible(new_psi):
            fell_back = False
    if fell_back:
        new_psi = _stabilized_euler(psi, rate_psi, k, V_star, lam_psi, ik, N)
    new_psi = new_psi + (psi.sum() - new_psi.sum()) / N
    if quadratic:
        to_prev2 = _shift_symbol(moved * (k + dt_prev + dt_prev2) / dt_prev, im2pi, N)
        predicted = np.fft.irfft((l0 * to_n) * psi_hat + (l1 * to_prev) * prev_hat
                                 + (l2 * to_prev2) * np.fft.rfft(prev2_psi), N)
    else:
        predicted = psi_star
    psi_error = new_psi - predicted
    if fell_back:
        psi_error = np.fft.irfft(np.fft.rfft(psi_error) * np.where(k * lam_psi <= 1.0, 1.0, 0.0), N)
    psi_scale = max(_largest_magnitude(new_psi), _largest_magnitude(psi))
    return new_theta, before, theta_error, theta_scale, new_psi, psi_error, psi_scale, order


# ---------------------------------------------------------------- a sample (diagnostics.sample)
#: the values :func:`sample_values` returns, in order
SAMPLE = ("theta", "area", "length", "E_bending", "E_phase", "centroid_x", "centroid_y", "tension_min",
          "tension_mean", "tension_max", "V_psi", "V_L", "phase_position", "psi_min", "psi_max", "stretching",
          "tail_theta", "tail_psi")


@jit
def _tail(f_hat, N):
    """spectral.spectral_tail."""
    total = 0.0
    for m in range(1, f_hat.size):
        total += f_hat[m].real ** 2 + f_hat[m].imag ** 2
    if total <= 0.0:
        return 0.0
    top = 0.0
    for m in range(int(math.ceil(N / 3.0)), f_hat.size):
        top += f_hat[m].real ** 2 + f_hat[m].imag ** 2
    return math.sqrt(top / total)


@jit
def _interpolate(spectrum, alpha, N):
    """The trigonometric interpolant at alpha of the samples whose fft / N is ``spectrum``
    (spectral.Spectral.interpolate: the Nyquist mode real, cos(pi N alpha)); e^{2 pi i m alpha} by
    powers of e^{2 pi i alpha} (one sine and cosine; 1e-15 relative at m = N / 2)."""
    step = complex(math.cos(2.0 * math.pi * alpha), math.sin(2.0 * math.pi * alpha))
    value = spectrum[0]
    power = 1.0 + 0j
    for m in range(1, N // 2):
        power *= step
        value += spectrum[m] * power + spectrum[N - m] * power.conjugate()
    return value + spectrum[N // 2] * math.cos(math.pi * N * alpha)


@jit
def _axis_point(z, z_hat, dz_hat, centroid, inclination):
    """diagnostics.axis_point: alpha where the ray centroid + r e^{i theta} meets the membrane
    (``z_hat``, ``dz_hat``: fft / N of z and of dz/dalpha = L e^{i theta})."""
    N = z.size
    rot = complex(math.cos(inclination), -math.sin(inclination))
    w = (z - centroid) * rot
    found = -1
    for j in range(N):
        after = (j + 1) % N
        if w[j].real > 0 and w[after].real > 0 and w[j].imag <= 0.0 < w[after].imag:
            found = j
            break
    if found < 0:
        best, j_best = -np.inf, 0
        for j in range(N):
            value = w[j].real - 10 * abs(w[j].imag)
            if value > best:
                best, j_best = value, j
        return j_best / N
    j = found
    g0, g1 = w[j].imag, w[(j + 1) % N].imag
    alpha = (j + g0 / (g0 - g1)) / N
    for _ in range(8):
        value = ((_interpolate(z_hat, alpha, N) - centroid) * rot).imag
        slope = (_interpolate(dz_hat, alpha, N) * rot).imag
        step = value / slope
        alpha -= step
        if abs(step) < 1e-14:
            break
    return alpha % 1.0


@jit
def sample_values(theta_tilde, psi, shift, z, tangent, curvature, velocity, tension_eff, psi_s, psi_t, psi_hat, V,
                  homogeneous, ikc, phase, phys):
    """diagnostics.sample's numbers of a state from its rates, in the order of :data:`SAMPLE` (area and
    length as they are: the caller makes them errors). ``phase``: e^{2 pi i j / N} at the nodes."""
    length, B1, B2, saturating, width, shear_rate, a0, eps, mobility, viscosity_ratio = phys
    N = z.size
    out = np.empty(len(SAMPLE))
    # moments of the enclosed region (geometry.moments), n = -i s
    origin = z.sum() / N
    sums = np.zeros(6)
    for j in range(N):
        x, y = z[j].real - origin.real, z[j].imag - origin.imag
        nx, ny = tangent[j].imag, -tangent[j].real
        sums[0] += 0.5 * (x * nx + y * ny)
        sums[1] += 0.5 * x * x * nx
        sums[2] += 0.5 * y * y * ny
        sums[3] += x ** 3 / 3.0 * nx
        sums[4] += 0.5 * x * x * y * nx
        sums[5] += y ** 3 / 3.0 * ny
    A, Sx, Sy, Sxx, Sxy, Syy = sums / N * length
    cx, cy = Sx / A, Sy / A
    centroid = origin + complex(cx, cy)
    Ixx, Ixy, Iyy = Sxx - A * cx * cx, Sxy - A * cx * cy, Syy - A * cy * cy
    inclination = 0.5 * math.atan2(2.0 * Ixy, Ixx - Iyy)
    # length (geometry.length_of)
    dz = _multiply_complex(z, ikc) * length
    perimeter = np.abs(dz).sum() / N
    # tension Lambda = Lambda~ - sigma, energies, psi's range
    lam_min, lam_max, lam_sum, bending, line = np.inf, -np.inf, 0.0, 0.0, 0.0
    psi_min, psi_max = np.inf, -np.inf
    for j in range(N):
        p = psi[j]
        well = 0.25 * p * p * (1.0 - p) ** 2
        lam = tension_eff[j] - (a0 / eps) * (well - 0.5 * eps * eps * psi_s[j] ** 2)
        lam_min, lam_max, lam_sum = min(lam_min, lam), max(lam_max, lam), lam_sum + lam
        s, _, _ = _law(p, saturating, width)
        bending += (B1 + (B2 - B1) * s) * curvature[j] ** 2
        line += well + 0.5 * eps * eps * psi_s[j] ** 2
        psi_min, psi_max = min(psi_min, p), max(psi_max, p)
    # the phase pattern relative to the material: sum psi_j e^{2 pi i j / N}
    Z, dZ = 0j, 0j
    for j in range(N):
        Z += psi[j] * phase[j]
        dZ += psi_t[j] * phase[j]
    if abs(Z) > 1e-12 * N:
        position = (math.atan2(Z.imag, Z.real) / (2 * math.pi) - shift) % 1.0
        V_psi = length * (dZ / Z).imag / (2 * math.pi)
    else:
        position, V_psi = np.nan, np.nan
    # the material point alpha = 0 relative to the long axis (geometry.moment_rates, diagnostics.axis_point)
    rates = np.zeros(6)
    for j in range(N):
        x, y = z[j].real - origin.real, z[j].imag - origin.imag
        u_n = tangent[j].imag * velocity[j].real - tangent[j].real * velocity[j].imag      # u . n
        w = u_n * length / N
        rates[0] += w
        rates[1] += x * w
        rates[2] += y * w
        rates[3] += x * x * w
        rates[4] += x * y * w
        rates[5] += y * y * w
    dA, dSx, dSy, dSxx, dSxy, dSyy = rates
    dcx, dcy = (dSx - cx * dA) / A, (dSy - cy * dA) / A
    dIxx = dSxx - dA * cx * cx - 2 * A * cx * dcx
    dIxy = dSxy - dA * cx * cy - A * (dcx * cy + cx * dcy)
    dIyy = dSyy - dA * cy * cy - 2 * A * cy * dcy
    z_hat, dz_hat = np.fft.fft(z) / N, np.fft.fft(tangent * length) / N
    a_axis = _axis_point(z, z_hat, dz_hat, centroid, inclination)
    dphi = ((Ixx - Iyy) * dIxy - Ixy * (dIxx - dIyy)) / ((Ixx - Iyy) ** 2 + 4 * Ixy ** 2)
    z_a = _interpolate(z_hat, a_axis, N)
    dz_a = _interpolate(dz_hat, a_axis, N)
    w_a = _interpolate(np.fft.fft(velocity - V * tangent) / N, a_axis, N)
    rot = complex(math.cos(inclination), -math.sin(inclination))
    da_axis = -((w_a - complex(dcx, dcy) - 1j * dphi * (z_a - centroid)) * rot).imag / (dz_a * rot).imag
    out[0], out[1], out[2] = inclination, A, perimeter
    out[3] = 0.5 * length * bending / N
    out[4] = length * (a0 / eps) * line / N
    out[5], out[6] = centroid.real, centroid.imag
    out[7], out[8], out[9] = lam_min, lam_sum / N, lam_max
    out[10], out[11], out[12] = V_psi, V - length * da_axis, position
    out[13], out[14] = psi_min, psi_max
    out[15] = _largest_magnitude(_stretching(tangent, velocity, ikc))
    out[16] = _tail(np.fft.rfft(theta_tilde), N)
    out[17] = 0.0 if homogeneous else _tail(psi_hat, N)
    return out


@jit
def _finite(values):
    for value in values:
        if not math.isfinite(value):
            return False
    return True


@jit
def soundness(theta, psi, rate_theta, rate_psi):
    """(the first of the four arrays with a non-finite value, -1 if none; min psi; max psi): the
    per-step part of diagnostics.health. ``rate_*`` of length 0 where there is none."""
    if not _finite(theta):
        return 0, np.nan, np.nan
    if not _finite(psi):
        return 1, np.nan, np.nan
    if not _finite(rate_theta):
        return 2, np.nan, np.nan
    if not _finite(rate_psi):
        return 3, np.nan, np.nan
    return -1, psi.min(), psi.max()


@jit
def spectral_tails(theta_tilde, psi):
    """(tail of theta_tilde, tail of psi) as :func:`sample_values` measures them (the initial tails
    the health check compares the samples' against: the same arithmetic, so equal at t = 0)."""
    N = theta_tilde.size
    return _tail(np.fft.rfft(theta_tilde), N), _tail(np.fft.rfft(psi), N)


def cache_is_warm() -> bool | None:
    """Whether numba's cache on disk holds the step's kernels, compiled from this source: False means
    the first step compiles them (~20-50 s, once per machine), None that it cannot tell. Asks numba's
    cache index (``_load_index``, private: it checks the source's stamp the way loading does), since
    numba offers no public question for it."""
    try:
        return all(bool(kernel._cache._cache_file._load_index()) for kernel in (shape_rates, flow_rates, sbdf2))
    except Exception:                     # noqa: BLE001 -- another numba's internals: say nothing
        return None
