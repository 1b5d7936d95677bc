"""Geometry of a closed, inextensible membrane in tangent-angle variables.

The membrane is described by the tangent angle theta(alpha) of N material
points, equispaced in arclength s = L alpha, and the mean position ``center``
of those points. theta = 2 pi alpha + theta_tilde with theta_tilde periodic; the
unit tangent is s = e^{i theta} (counter-clockwise), the outward normal
n = -i s = (sin theta, -cos theta) and the curvature H = d theta / ds (> 0 on
a convex curve, so that d s/ds = -H n and d n/ds = H s).

Positions are complex numbers z = x + i y:  z(alpha) = center + L * int e^{i theta},
which closes only if mean(e^{i theta}) = 0; :func:`close_curve` restores
that after each time step.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize, special
from scipy.linalg import lapack

from hpcves.model.params import ConfigError
from hpcves.numerics.reductions import largest_magnitude
from hpcves.numerics.spectral import Spectral


# ---------------------------------------------------------------------------
# initial shape: ellipse of given perimeter and excess length
# ---------------------------------------------------------------------------
def ellipse_perimeter(a: float, b: float) -> float:
    """Perimeter 4 a E(1 - b^2/a^2) of the ellipse with semi-axes a >= b."""
    return 4.0 * a * special.ellipe(1.0 - (b / a) ** 2)


def excess_length_of_ellipse(q: float) -> float:
    """Delta = L / R - 2 pi for the ellipse with axis ratio q = b/a (R = sqrt(A/pi))."""
    return ellipse_perimeter(1.0, q) / np.sqrt(q) - 2.0 * np.pi


def ellipse_for_excess_length(length: float, excess_length: float) -> tuple[float, float]:
    """Semi-axes (a, b), a >= b, of the ellipse with perimeter ``length`` and excess length Delta."""
    if excess_length < 0:
        raise ConfigError(f"excess length {excess_length}: no ellipse has a negative excess length")
    if excess_length == 0:
        q = 1.0
    else:
        q_min = 1e-6
        if excess_length_of_ellipse(q_min) < excess_length:
            raise ConfigError(f"excess length {excess_length}: beyond any ellipse with axis ratio > 1e-6")
        q = optimize.brentq(lambda x: excess_length_of_ellipse(x) - excess_length, q_min, 1.0,
                            xtol=1e-15, rtol=1e-15, maxiter=200)
    a = length / ellipse_perimeter(1.0, q)
    return a, q * a


def ellipse_equal_arclength(a: float, b: float, N: int) -> tuple[np.ndarray, np.ndarray]:
    """Ellipse parameters t_j with equal arclength between x = a cos t, y = b sin t.

    Returns (t, theta): t_j in [0, 2 pi) at arclength j P / N from (a, 0), and the
    tangent angle theta_j of the curve there (continuous, theta_0 = pi/2).
    The arclength S(t) = a [E(pi/2 | m) - E(pi/2 - t | m)], m = 1 - b^2/a^2, is
    inverted by Newton's method to round-off.
    """
    m = 1.0 - (b / a) ** 2
    E_quarter = special.ellipeinc(np.pi / 2, m)
    perimeter = 4.0 * a * E_quarter
    s_target = perimeter * np.arange(N) / N

    def arclength(t):
        return a * (E_quarter - special.ellipeinc(np.pi / 2 - t, m))

    def speed(t):
        return np.sqrt(a**2 * np.sin(t) ** 2 + b**2 * np.cos(t) ** 2)

    t = 2.0 * np.pi * np.arange(N) / N
    for _ in range(60):
        step = (arclength(t) - s_target) / speed(t)
        t = t - step
        if np.max(np.abs(step)) < 1e-15:
            break
    theta = np.unwrap(np.arctan2(b * np.cos(t), -a * np.sin(t)))
    theta += np.pi / 2 - theta[0]
    return t, theta


#: Weights of the Fourier modes |k| = 0, 1, 2, 3, 4 of the ellipse's tangent-angle excess that the
#: smoothed start keeps (the rest are dropped). The halves are what the authors' code keeps of modes 3
#: and 4: it zeroes one side of the FFT and takes the real part (docs/numerics.md, "Initial shape").
SMOOTHING_WEIGHTS = (1.0, 1.0, 1.0, 0.5, 0.5)


def ellipse_angle_modes(a: float, b: float, kmax: int = 4, tol: float = 1e-14) -> np.ndarray:
    """Fourier coefficients c_k, k = -kmax..kmax, of theta(alpha) - pi/2 - 2 pi alpha on the ellipse.

    alpha = s / P is the arclength from (a, 0) over the perimeter. The trapezoid rule on M
    equal-arclength nodes converges geometrically; M doubles from 512 until the coefficients move
    by less than ``tol`` (a thin ellipse needs more nodes).
    """
    k = np.arange(-kmax, kmax + 1)
    previous = None
    for M in 2 ** np.arange(9, 21):
        _, theta = ellipse_equal_arclength(a, b, int(M))
        modes = np.fft.fft(theta - np.pi / 2 - 2.0 * np.pi * np.arange(M) / M)[k] / M
        if previous is not None and np.max(np.abs(modes - previous)) < tol:
            return modes
        previous = modes
    raise ConfigError(f"ellipse {a:g} x {b:g}: tangent-angle modes not converged on 2^20 nodes")


def smoothed_ellipse(a: float, b: float, N: int) -> np.ndarray:
    """Tangent angle at N equal-arclength nodes of the smoothed ellipse (the authors' start, SPEC section 7).

    theta(alpha) = pi/2 + 2 pi alpha + c sum_{|k| <= 4} w_|k| c_k e^{2 pi i k alpha}, c_k from
    :func:`ellipse_angle_modes`, w = SMOOTHING_WEIGHTS, and the factor c > 1 the one that gives back
    the ellipse's area pi a b at its perimeter: perimeter and area, hence the excess length, are the
    ellipse's; the tips are blunter. Defined by the continuous curve, so the same shape at every N.
    """
    alpha = np.arange(N) / N
    if a == b:
        return np.pi / 2 + 2.0 * np.pi * alpha
    modes = ellipse_angle_modes(a, b)
    kmax = modes.size // 2
    k = np.arange(-kmax, kmax + 1)
    weighted = modes * np.asarray(SMOOTHING_WEIGHTS)[np.abs(k)]

    def angle(alpha):
        return np.pi / 2 + 2.0 * np.pi * alpha, np.real(np.exp(2j * np.pi * np.outer(alpha, k)) @ weighted)

    fine = Spectral(1024, ellipse_perimeter(a, b), backend="numpy")
    base, excess = angle(fine.alpha)
    target = np.pi * a * b

    def area_over(c):
        return enclosed_area(base + c * excess, fine) - target

    low, high = 1.0, 1.25
    if area_over(low) <= 0:
        raise ConfigError(f"ellipse {a:g} x {b:g}: its smoothed shape is not rounder than itself")
    while area_over(high) > 0:
        low, high = high, 1.25 * high
        if high > 100:
            raise ConfigError(f"ellipse {a:g} x {b:g}: no smoothed shape has its area")
    c = optimize.brentq(area_over, low, high, xtol=1e-15, rtol=1e-15, maxiter=200)
    base, excess = angle(alpha)
    return base + c * excess


# ---------------------------------------------------------------------------
# closed curves in tangent-angle form
# ---------------------------------------------------------------------------
def closure_defect(theta: np.ndarray) -> complex:
    """mean(e^{i theta}) -- zero for a closed curve."""
    return np.mean(np.exp(1j * theta))


def _closure_step(theta: np.ndarray, e: np.ndarray) -> np.ndarray:
    """One Newton step towards mean(e^{i theta}) = 0 (e = e^{i theta}), minimal l2 norm.

    Corrections delta theta = q cos theta - p sin theta are the gradient
    directions of the two constraints.
    """
    n = theta.size
    c, s = e.real, e.imag
    defect = e.sum() / n
    ss, cs, cc = np.dot(s, s) / n, np.dot(c, s) / n, np.dot(c, c) / n
    det = ss * cc - cs * cs
    p = -(cc * defect.real + cs * defect.imag) / det
    q = -(cs * defect.real + ss * defect.imag) / det
    return theta + (q * c - p * s)


def close_curve(theta: np.ndarray, tol: float = 1e-15, max_iterations: int = 4) -> np.ndarray:
    """The nearest (in the l2 sense) tangent angle whose curve closes: mean(e^{i theta}) = 0."""
    theta = np.array(theta, dtype=float)
    for _ in range(max_iterations):
        e = np.exp(1j * theta)
        if abs(e.sum()) < tol * theta.size:
            break
        theta = _closure_step(theta, e)
    return theta


def _area_from_tangent(tangent: np.ndarray, sp: Spectral) -> float:
    """A = 1/2 oint z . n ds with z = int e^{i theta} ds, n = -i e: z . n = -Im(conj(e) z)."""
    return _area(tangent, sp.antiderivative_complex(tangent, 0.0), sp)


def enclosed_area(theta: np.ndarray, sp: Spectral) -> float:
    """Area of the closed curve with tangent angle theta (full angle) and length sp.length."""
    return _area_from_tangent(np.exp(1j * theta), sp)


#: project_closed stops once its last correction times its first -- the size of
#: the defect that remains -- is below this (area then within ~1e-12 relative)
PROJECTION_REMAINDER = 1e-12


def project_closed(theta: np.ndarray, sp: Spectral, area: float | None = None):
    """Project a tangent angle (full angle theta) onto closed curves of a given area.

    Closure alone (``area`` None): one Newton step on mean(e^{i theta}) = 0 (see
    :func:`close_curve`). With an area, the three constraints

        Re sum e^{i theta} = 0,   Im sum e^{i theta} = 0,   A(theta) = area

    are solved together by Newton's method for a correction
    delta theta = lam_1 (-sin theta) + lam_2 cos theta + lam_3 theta_tilde: the
    closure directions of :func:`close_curve` and a scaling of the periodic part
    theta_tilde of theta about its mean (at fixed length a larger deviation from
    the circle encloses less area). The area gradient is exact for the discrete
    area (:func:`area_gradient`). The Jacobian is formed once, at the incoming
    theta (a chord method): after a time step the defects are of the size of the
    local error (1e-7 relative), so the first correction is ~1e-6 and each
    further one is smaller by about that factor. Steps stop once the constraints
    hold (closure to 1e-15, area to 1e-13 relative) or the last correction times
    the first -- the size of what remains -- is below PROJECTION_REMAINDER
    (1e-12): after a time step that is one Newton step, which leaves the area
    within 6e-13 relative and mean(e^{i theta}) within 7e-14 (a second step,
    ~15 us at N = 128, would bring them to 2e-14 and 1e-15). A (near) circle, whose
    area does not change under scaling (|dA/dlam_3| <= 1e-12 A), is only closed.
    Returns (theta, area before the correction).
    """
    if area is None:
        return _closure_step(theta, np.exp(1j * theta)), None
    rows = np.empty((4, sp.N))        # directions: scaling, -sin, cos; then the area gradient
    direction, sin_direction, cos_direction, gradient = rows[0], rows[1], rows[2], rows[3]
    np.subtract(theta, sp.circle_angle, out=direction)
    direction -= direction.sum() / sp.N
    e = np.exp(1j * theta)
    z = sp.antiderivative_complex(e, 0.0)
    A = before = _area(e, z, sp)
    np.negative(e.imag, out=sin_direction)
    cos_direction[:] = e.real
    area_gradient(e, z, sp, out=gradient)
    jacobian = rows[1:] @ rows[:3].T          # d(Re sum e, Im sum e, A) / d(lam)
    if abs(jacobian[2, 0]) <= 1e-12 * area:  # (nearly) a circle: no scaling direction
        return _closure_step(theta, e), before
    first = None
    for _ in range(6):
        defect = e.sum()
        if abs(A - area) <= 1e-13 * area and abs(defect) <= 1e-15 * sp.N:
            break
        lam, info = _solve3(jacobian, np.array([-defect.real, -defect.imag, area - A]))
        if info != 0:
            return _closure_step(theta, e), before
        correction = lam @ rows[:3]
        theta = theta + correction
        size = largest_magnitude(correction)
        first = size if first is None else first
        if size * first <= PROJECTION_REMAINDER:    # what remains: O(this correction x the first)
            break
        e = np.exp(1j * theta)
        z = sp.antiderivative_complex(e, 0.0)
        A = _area(e, z, sp)
    return theta, before


def _area(tangent: np.ndarray, z: np.ndarray, sp: Spectral) -> float:
    """A = 1/2 oint z . n ds = -(L / 2N) Im(sum conj(e) z), z the mean-free antiderivative of e."""
    return -0.5 * sp.length * float(np.vdot(tangent, z).imag) / sp.N


def area_gradient(tangent: np.ndarray, z: np.ndarray, sp: Spectral, out=None) -> np.ndarray:
    """dA/dtheta_j = (L / N) Re(conj(e_j) z_j) = (L / N) z_j . s_j of the discrete area.

    With z = Z e (Z the spectral antiderivative, real and skew: Z^T = -Z),
    dA = -(L/N) Im(delta e^H z) and delta e = i e delta theta. ``z`` must be the
    mean-free antiderivative that the area was computed from.
    """
    out = np.empty(sp.N) if out is None else out
    np.multiply(tangent.real, z.real, out=out)
    out += tangent.imag * z.imag
    out *= sp.length / sp.N
    return out


def _solve3(matrix, rhs):
    _, _, x, info = lapack.dgesv(matrix, rhs)
    return x, info


@dataclass(frozen=True)
class Shape:
    """Material points of a closed curve and their local frame."""

    z: np.ndarray            # positions x + i y
    tangent: np.ndarray      # e^{i theta}
    curvature: np.ndarray    # H = d theta / ds

    @property
    def normal(self) -> np.ndarray:
        """Outward normal n = -i s."""
        return -1j * self.tangent


def shape_from_angle(theta_tilde: np.ndarray, center: complex, sp: Spectral) -> Shape:
    """Positions, tangent and curvature of the curve theta = 2 pi alpha + theta_tilde."""
    theta = sp.circle_angle + theta_tilde
    tangent = np.exp(1j * theta)
    z = sp.antiderivative_complex(tangent, center)
    curvature = 2.0 * np.pi / sp.length + sp.ds(theta_tilde)
    return Shape(z=z, tangent=tangent, curvature=curvature)


# ---------------------------------------------------------------------------
# measures of a closed curve (trapezoid rule: spectrally accurate)
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Moments:
    """Area moments of the enclosed region (about ``origin``)."""

    area: float
    centroid: complex
    Ixx: float     # central second moments
    Ixy: float
    Iyy: float

    @property
    def inclination(self) -> float:
        """Angle of the long principal axis with the x axis, in (-pi/2, pi/2]."""
        return principal_angle(self.Ixx, self.Ixy, self.Iyy)


def principal_angle(Ixx, Ixy, Iyy):
    """1/2 atan2(2 Ixy, Ixx - Iyy): direction of the larger eigenvalue, in (-pi/2, pi/2]."""
    return 0.5 * np.arctan2(2.0 * Ixy, Ixx - Iyy)


def _flux_integrands(z, normal, origin):
    """Integrands F . n of the fields whose divergence is 1, x, y, x^2, xy, y^2."""
    x, y = (z - origin).real, (z - origin).imag
    nx, ny = normal.real, normal.imag
    return np.stack([
        0.5 * (x * nx + y * ny),
        0.5 * x * x * nx,
        0.5 * y * y * ny,
        x**3 / 3.0 * nx,
        0.5 * x * x * y * nx,
        y**3 / 3.0 * ny,
    ])


def moments(z: np.ndarray, normal: np.ndarray, length: float) -> Moments:
    """Area, centroid and central second moments by the divergence theorem."""
    origin = z.mean()
    A, Sx, Sy, Sxx, Sxy, Syy = _flux_integrands(z, normal, origin).mean(axis=1) * length
    cx, cy = Sx / A, Sy / A
    return Moments(area=A, centroid=origin + complex(cx, cy),
                   Ixx=Sxx - A * cx * cx, Ixy=Sxy - A * cx * cy, Iyy=Syy - A * cy * cy)


def moment_rates(z, normal, normal_velocity, length, m: Moments):
    """Time derivatives (dA, dcentroid, dIxx, dIxy, dIyy) of the moments.

    Reynolds' transport theorem: d/dt int_Omega h dA = oint h (u . n) ds.
    """
    origin = z.mean()
    x, y = (z - origin).real, (z - origin).imag
    w = normal_velocity * length / z.size
    dA = w.sum()
    dSx, dSy = (x * w).sum(), (y * w).sum()
    dSxx, dSxy, dSyy = (x * x * w).sum(), (x * y * w).sum(), (y * y * w).sum()
    A = m.area
    cx, cy = (m.centroid - origin).real, (m.centroid - origin).imag
    dcx, dcy = (dSx - cx * dA) / A, (dSy - cy * dA) / A
    dIxx = dSxx - dA * cx * cx - 2 * A * cx * dcx
    dIxy = dSxy - dA * cx * cy - A * (dcx * cy + cx * dcy)
    dIyy = dSyy - dA * cy * cy - 2 * A * cy * dcy
    return dA, complex(dcx, dcy), dIxx, dIxy, dIyy


def length_of(z: np.ndarray, sp: Spectral) -> float:
    """Perimeter of the closed curve through the points z (spectral |dz/dalpha|)."""
    dz_dalpha = sp.ds_complex(z) * sp.length
    return float(np.mean(np.abs(dz_dalpha)))


def excess_length(area: float, length: float) -> float:
    """Delta = L / sqrt(A / pi) - 2 pi."""
    return length / np.sqrt(area / np.pi) - 2.0 * np.pi
