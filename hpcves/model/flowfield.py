"""The velocity anywhere in the plane, from the membrane's force; pure functions.

With matched viscosities the flow is the single layer of the membrane force f
(SPEC section 1; Pozrikidis, *Boundary Integral and Singularity Methods*, 1992,
ch. 2):

    u(x) = u_inf(x) + 1/(4 pi) int_gamma G(x - y) f(y) ds(y),
    G(r) = -log|r| I + r r^T / |r|^2,        u_inf(x) = S (x_2, 0),

continuous across the membrane, where it equals the membrane velocity.

Three zones, by the distance d of a target from the nearest node (h = L/N):

* **far** (d >= FAR h): the trapezoid rule on the N nodes. Its error falls like
  exp(-2 pi d / h) (the integrand is periodic and analytic, its nearest
  singularity d away): round-off on an ellipse, 1e-11 of |f| at 6 h from the
  tip of a Delta = 2.3 shape (N = 128, tip radius 3.7 h);
* **near** (D <= d < FAR h, D = NEAR h / UPSAMPLE = 5 h / 32): the same rule on
  the curve and the force Fourier-interpolated to UPSAMPLE N nodes, at
  round-off from D on;
* **close** (d < D): interpolation along the normal through the nearest
  membrane point p, as in Ying, Biros & Zorin (J. Comput. Phys. 219, 2006) and
  the 2-D vesicle codes after them (Quaife & Biros, J. Comput. Phys. 274,
  2014): the polynomial in the distance through the single layer at p (the
  membrane velocity less u_inf, d = 0) and the near-zone values at d = D, 2D,
  ..., CLOSE_POINTS D on the target's side. The velocity is smooth on each side
  up to the membrane (its normal derivative jumps across it), so this converges
  like (CLOSE_POINTS D / rho)^(CLOSE_POINTS + 1), rho the scale on which u
  varies off the membrane: the radius of curvature and the force's shortest
  wavelength along it (3e-9 of max |u| on a circle with force modes up to 9 at
  N = 64, 2e-7 with UPSAMPLE = 16, 8e-6 with 8; 4e-8 at the Delta = 2.3 tip).
  It needs the curve's distance to any other part of itself to exceed
  CLOSE_POINTS D (0.94 h).

With a viscosity contrast lambda = eta_in / eta_out (Pozrikidis 1992, sec. 5.3; the membrane's own
equation in numerics/double_layer.py) the membrane velocity u adds its double layer,

    outside:  u(x) = u_inf(x) + SLP[f](x) + DLP[u](x),
    inside:   lambda u(x) = u_inf(x) + SLP[f](x) + DLP[u](x),
    DLP[u](x) = ((1 - lambda)/pi) int (r . n)(r r^T)/|r|^4 u(y) ds(y),   r = x - y,

whose limits on the membrane differ from its principal value by +-(1 - lambda)/2 u, so that both
sides meet u there. It is evaluated by the same three zones (its kernel is as near-singular as the
single layer's), the close zone interpolating u - u_inf of the target's side; which side a far
target lies on is the winding number of the curve about it (the trapezoid rule again).

Tested against the closed-form single layer of Fourier-mode forces on a circle
(tests/test_flowfield.py) from 1e-6 h to 10 h inside and outside. The cost is
that of the direct sums: 0.3 s for a 120 x 120 grid around a Delta = 2.3 shape
at N = 128 (a tenth of the targets near the membrane).
"""
from __future__ import annotations

import numpy as np

from hpcves.model.forces import bending_force, tension_force
from hpcves.model.params import Physics
from hpcves.model.phasefield import line_tension
from hpcves.numerics.spectral import Spectral

FAR = 5.0              # the plain trapezoid rule from FAR node spacings on
UPSAMPLE = 32          # the near zone's quadrature: UPSAMPLE times the nodes
NEAR = 5.0             # the near zone's rule is exact to round-off from NEAR of its spacings on
CLOSE_POINTS = 6       # off-membrane values in the close zone's interpolation
MAX_NEWTON = 20       # iterations for the nearest membrane point (from the nearest node)
_CHUNK = 2_000_000     # targets x nodes per block of the direct sums (memory)


def traction(z: np.ndarray, psi: np.ndarray, tension: np.ndarray, curvature: np.ndarray,
             physics: Physics) -> np.ndarray:
    """The membrane force f = f_b + d(Lambda~ s)/ds (complex, per unit length) of a snapshot.

    The snapshot's nodes are equispaced in arclength; its ``tension`` is Lambda =
    Lambda~ - sigma (diagnostics.tension), so Lambda~ = Lambda + sigma(psi, psi_s).
    """
    z = np.asarray(z, dtype=complex)
    N = z.size
    dz = _per_alpha(N).ds_complex(z)
    length = float(np.sum(np.abs(dz)) / N)
    sp = Spectral(N, length, backend="numpy")
    tangent = dz / np.abs(dz)
    psi = np.asarray(psi, dtype=float)
    psi_s = sp.ds(psi)
    tension_eff = np.asarray(tension, dtype=float) + line_tension(psi, psi_s, physics.a0, physics.epsilon)
    return bending_force(np.asarray(curvature, dtype=float), psi, psi_s, tangent, physics, sp) \
        + tension_force(tension_eff, tangent, sp)


def velocity(targets, z: np.ndarray, force: np.ndarray, membrane_velocity: np.ndarray,
             shear_rate: float, viscosity_ratio: float = 1.0) -> np.ndarray:
    """u at ``targets`` (complex x + i y, any shape) of the flow driven by ``force`` on the closed
    curve ``z`` (N nodes, equally spaced in the parameter) whose velocity is ``membrane_velocity``
    (e.g. Flow.velocity or a snapshot's velocity), with ``viscosity_ratio`` = eta_in / eta_out."""
    targets = np.asarray(targets, dtype=complex)
    x = targets.ravel()
    z, force = np.asarray(z, dtype=complex), np.asarray(force, dtype=complex)
    membrane_velocity = np.asarray(membrane_velocity, dtype=complex)
    disturbance = membrane_velocity - shear_rate * z.imag            # u - u_inf on the membrane
    N = z.size
    contrast = viscosity_ratio != 1.0
    coarse = _Curve(z, force, membrane_velocity if contrast else None, viscosity_ratio)
    fine = coarse.upsampled(UPSAMPLE * N)
    h = coarse.length / N
    D = NEAR * h / UPSAMPLE
    u = np.empty(x.size, dtype=complex)
    nearest = np.min(np.abs(x[:, None] - z[None, :]), axis=1) if x.size * N <= _CHUNK else \
        np.concatenate([np.min(np.abs(part[:, None] - z[None, :]), axis=1)
                        for part in np.array_split(x, x.size * N // _CHUNK + 1)])
    far = nearest >= FAR * h
    inside = coarse.winding(x[far]) != 0 if contrast else None
    u[far] = coarse.disturbance(x[far], inside, shear_rate)
    rest = np.flatnonzero(~far)
    if rest.size:
        alpha, point, normal, distance = coarse.nearest_points(x[rest])
        outward = np.real(np.conj(x[rest] - point) * normal) >= 0.0
        close = distance < D
        near = rest[~close]
        u[near] = fine.disturbance(x[near], None if not contrast else ~outward[~close], shear_rate)
        if np.any(close):
            u[rest[close]] = _along_normal(fine, x[rest[close]], alpha[close], point[close], normal[close],
                                           distance[close], outward[close], disturbance, D, shear_rate)
    u += shear_rate * x.imag
    return u.reshape(targets.shape)


def _along_normal(fine, x, alpha, point, normal, distance, outward, on_membrane, D, shear_rate):
    """The close zone: the polynomial through u - u_inf at p (``on_membrane``, at the nodes) and the
    near-zone values at p + side n k D, on the target's side (``outward``)."""
    side = np.where(outward, 1.0, -1.0)
    steps = np.arange(1, CLOSE_POINTS + 1) * D
    probes = point[:, None] + (side * normal)[:, None] * steps[None, :]
    values = np.empty((x.size, CLOSE_POINTS + 1), dtype=complex)
    values[:, 0] = _per_alpha(on_membrane.size).interpolate(on_membrane, alpha)
    inside = None if fine.velocity is None else np.repeat(~outward, CLOSE_POINTS)
    values[:, 1:] = fine.disturbance(probes.ravel(), inside, shear_rate).reshape(probes.shape)
    nodes = np.concatenate([[0.0], steps])
    return np.sum(_lagrange_weights(nodes, distance) * values, axis=1)


def _lagrange_weights(nodes: np.ndarray, t: np.ndarray) -> np.ndarray:
    """w[i, k] = l_k(t_i), the Lagrange basis of ``nodes`` at each ``t``."""
    w = np.ones((t.size, nodes.size))
    for k, node in enumerate(nodes):
        for j, other in enumerate(nodes):
            if j != k:
                w[:, k] *= (t - other) / (node - other)
    return w


def _per_alpha(n: int) -> Spectral:
    """Calculus in the curve parameter alpha in [0, 1) of n samples (a length of 1: d/ds is d/d alpha)."""
    return Spectral(n, 1.0, backend="numpy")


class _Curve:
    """Nodes, force (and, with a contrast, velocity) and arclength weights of one quadrature of the curve."""

    def __init__(self, z: np.ndarray, force: np.ndarray, velocity: np.ndarray | None = None,
                 viscosity_ratio: float = 1.0):
        self.z, self.force, self.velocity, self.viscosity_ratio = z, force, velocity, viscosity_ratio
        n = z.size
        self.dz = _per_alpha(n).ds_complex(z)
        self.weight = np.abs(self.dz) / n                  # ds = |z'(alpha)| d alpha, trapezoid
        self.length = float(np.sum(self.weight))
        self.orientation = 1.0 if np.sum(np.imag(np.conj(z) * self.dz)) > 0 else -1.0   # +1: counterclockwise

    def upsampled(self, n: int) -> _Curve:
        velocity = None if self.velocity is None else _resample(self.velocity, n)
        return _Curve(_resample(self.z, n), _resample(self.force, n), velocity, self.viscosity_ratio)

    def disturbance(self, x: np.ndarray, inside: np.ndarray | None, shear_rate: float) -> np.ndarray:
        """u - u_inf at ``x`` off the curve: the single layer, and with a contrast (``inside`` the targets
        within the curve) the double layer, divided by lambda inside with u_inf (module docstring)."""
        if self.velocity is None:
            return self.single_layer(x)
        total = self.single_layer(x) + self.double_layer(x) + shear_rate * x.imag
        total[inside] /= self.viscosity_ratio
        return total - shear_rate * x.imag

    def single_layer(self, x: np.ndarray) -> np.ndarray:
        """(1/4 pi) sum_j w_j G(x - z_j) f_j: the trapezoid rule (no u_inf)."""
        out = np.empty(x.size, dtype=complex)
        rows = max(1, _CHUNK // self.z.size)
        fw = self.force * self.weight
        for start in range(0, x.size, rows):
            r = x[start:start + rows, None] - self.z[None, :]
            r2 = np.abs(r) ** 2
            terms = -0.5 * np.log(r2) * fw + r * (np.real(np.conj(r) * fw) / r2)
            out[start:start + rows] = terms.sum(axis=1) / (4.0 * np.pi)
        return out

    def double_layer(self, x: np.ndarray) -> np.ndarray:
        """((1 - lambda)/pi) sum_j w_j (r . n_j) r (r . u_j) / |r|^4, r = x - z_j: the trapezoid rule."""
        out = np.empty(x.size, dtype=complex)
        rows = max(1, _CHUNK // self.z.size)
        normal = -1j * self.orientation * self.dz / np.abs(self.dz)          # outward
        scale = (1.0 - self.viscosity_ratio) / np.pi
        for start in range(0, x.size, rows):
            r = x[start:start + rows, None] - self.z[None, :]
            r2 = np.abs(r) ** 2
            k = np.real(np.conj(r) * normal) * np.real(np.conj(r) * self.velocity) * self.weight / (r2 * r2)
            out[start:start + rows] = scale * (r * k).sum(axis=1)
        return out

    def winding(self, x: np.ndarray) -> np.ndarray:
        """How many times the curve winds around each target (0 outside; the trapezoid rule of
        (1 / 2 pi i) oint dz / (z - x), exact to round-off away from the curve), rounded."""
        out = np.empty(x.size)
        rows = max(1, _CHUNK // self.z.size)
        for start in range(0, x.size, rows):
            terms = self.dz[None, :] / (self.z[None, :] - x[start:start + rows, None])
            out[start:start + rows] = np.imag(terms.sum(axis=1)) / (2.0 * np.pi * self.z.size)
        return np.rint(out)

    def nearest_points(self, x: np.ndarray):
        """(alpha, point, outward unit normal, distance) of the membrane point nearest each target:
        the nearest node, then Newton on d/d alpha |z(alpha) - x|^2 = 0 for the interpolant."""
        n = self.z.size
        index = np.empty(x.size, dtype=int)
        rows = max(1, _CHUNK // n)
        for start in range(0, x.size, rows):
            index[start:start + rows] = np.argmin(np.abs(x[start:start + rows, None] - self.z[None, :]), axis=1)
        alpha = index / n
        sp = _per_alpha(n)
        levels = np.stack([self.z, self.dz, sp.ds_complex(self.dz)])       # z and its alpha-derivatives
        for _ in range(MAX_NEWTON):
            p, dp, d2p = sp.interpolate(levels, alpha)
            gap = p - x
            slope = np.real(np.conj(gap) * dp)
            curve = np.abs(dp) ** 2 + np.real(np.conj(gap) * d2p)
            step = np.clip(slope / curve, -0.5 / n, 0.5 / n)        # at most half a node a step
            alpha = alpha - step
            if np.max(np.abs(step)) < 1e-14:
                break
        p, dp = sp.interpolate(levels[:2], alpha)
        normal = -1j * self.orientation * dp / np.abs(dp)
        return alpha % 1.0, p, normal, np.abs(x - p)


def _resample(samples: np.ndarray, n: int) -> np.ndarray:
    """The trigonometric interpolant of N periodic samples at n >= N equispaced points."""
    N = samples.size
    c = np.fft.fft(samples)
    padded = np.zeros(n, dtype=complex)
    half = N // 2
    padded[:half] = c[:half]
    padded[n - half + 1:] = c[half + 1:]
    padded[half] = 0.5 * c[half]                         # Nyquist split between +-N/2
    padded[n - half] = 0.5 * c[half]
    return np.fft.ifft(padded) * (n / N)


def around_snapshot(snapshot: dict, physics: Physics, targets) -> np.ndarray:
    """u (lab frame) at ``targets`` for one snapshot: its nodes ``x``, ``y`` and ``psi``,
    ``tension``, ``curvature`` and membrane velocity ``velocity_x``, ``velocity_y`` there
    (diagnostics.snapshot), under the case's ``physics`` (its viscosity ratio included)."""
    z = np.asarray(snapshot["x"]) + 1j * np.asarray(snapshot["y"])
    force = traction(z, snapshot["psi"], snapshot["tension"], snapshot["curvature"], physics)
    membrane = np.asarray(snapshot["velocity_x"]) + 1j * np.asarray(snapshot["velocity_y"])
    return velocity(targets, z, force, membrane, physics.shear_rate, physics.viscosity_ratio)
