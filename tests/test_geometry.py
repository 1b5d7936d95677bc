import numpy as np
import pytest
from scipy import integrate

from conftest import make_solver
from hpcves.model import geometry
from hpcves.model.params import REFERENCE_EXCESS_LENGTH, REFERENCE_LENGTH, ConfigError, Physics
from hpcves.numerics.spectral import Spectral


def test_the_reference_ellipse_has_the_published_excess_length():
    # the 1/2 : 1/3 ellipse has perimeter 2.6442 and excess length 0.19385... ("0.194", SPEC section 1)
    assert geometry.ellipse_perimeter(0.5, 1 / 3) == pytest.approx(REFERENCE_LENGTH, abs=5e-5)
    assert REFERENCE_EXCESS_LENGTH == pytest.approx(geometry.excess_length_of_ellipse(2 / 3), rel=1e-14, abs=0)
    assert Physics().excess_length == REFERENCE_EXCESS_LENGTH                   # the default
    a, b = geometry.ellipse_for_excess_length(REFERENCE_LENGTH, REFERENCE_EXCESS_LENGTH)
    assert b / a == pytest.approx(2 / 3, rel=1e-12)
    assert geometry.ellipse_perimeter(a, b) == pytest.approx(REFERENCE_LENGTH, rel=1e-13)
    assert geometry.excess_length(np.pi * a * b, REFERENCE_LENGTH) == pytest.approx(REFERENCE_EXCESS_LENGTH,
                                                                                    abs=1e-13)
    a, b = geometry.ellipse_for_excess_length(REFERENCE_LENGTH, 0.194)          # the rounded value: its own shape
    assert b / a == pytest.approx(0.666564, rel=1e-6)
    assert geometry.excess_length(np.pi * a * b, REFERENCE_LENGTH) == pytest.approx(0.194, abs=1e-12)


@pytest.mark.parametrize("delta", [0.0, 0.94, 2.30])
def test_every_nonnegative_excess_length_has_an_ellipse(delta):
    a, b = geometry.ellipse_for_excess_length(REFERENCE_LENGTH, delta)
    assert geometry.excess_length(np.pi * a * b, REFERENCE_LENGTH) == pytest.approx(delta, abs=1e-11)


def test_negative_excess_length_is_refused():
    with pytest.raises(ConfigError, match="negative"):
        geometry.ellipse_for_excess_length(REFERENCE_LENGTH, -0.1)


def test_equal_arclength_nodes_reproduce_the_ellipse():
    N, a, b = 128, 0.5, 1 / 3
    t, theta = geometry.ellipse_equal_arclength(a, b, N)
    x, y = a * np.cos(t), b * np.sin(t)
    perimeter = geometry.ellipse_perimeter(a, b)
    for j in (1, 7, 23, 40, 63, 127):                              # arclength from (a, 0), independently
        arc, _ = integrate.quad(lambda u: np.hypot(a * np.sin(u), b * np.cos(u)), 0.0, t[j], epsabs=1e-14)
        assert arc == pytest.approx(j * perimeter / N, abs=1e-12)
    sp = Spectral(N, geometry.ellipse_perimeter(a, b))
    theta = geometry.close_curve(theta)
    z = sp.antiderivative_complex(np.exp(1j * theta), 0.0)
    assert np.abs(z - (x + 1j * y)).max() < 1e-13             # spectral: 2e-10 already at N = 64
    m = geometry.moments(z, -1j * np.exp(1j * theta), sp.length)
    assert m.area == pytest.approx(np.pi * a * b, rel=1e-12)
    assert abs(m.inclination) < 1e-12 and abs(m.centroid) < 1e-12


def test_inclination_of_a_rotated_ellipse():
    N, a, b, phi = 64, 0.5, 0.3, 0.7
    t = 2 * np.pi * np.arange(N) / N
    z = (a * np.cos(t) + 1j * b * np.sin(t)) * np.exp(1j * phi) + (0.2 - 0.1j)
    sp = Spectral(N, 1.0)
    dz = sp.ds_complex(z)
    normal = -1j * dz / np.abs(dz)
    # the curve is not arclength-parametrised here, so integrate with |dz/dt| weights
    m = geometry.moments(z, normal * np.abs(dz) / np.abs(dz).mean(), np.abs(dz).mean())
    assert m.inclination == pytest.approx(phi, abs=1e-10)
    assert m.area == pytest.approx(np.pi * a * b, rel=1e-10)
    assert m.centroid == pytest.approx(0.2 - 0.1j, abs=1e-10)


def test_projection_closes_the_curve_and_restores_the_area(rng):
    N = 64
    sp = Spectral(N, REFERENCE_LENGTH)
    a, b = geometry.ellipse_for_excess_length(REFERENCE_LENGTH, 0.6)
    theta = geometry.close_curve(geometry.ellipse_equal_arclength(a, b, N)[1])
    target = geometry.enclosed_area(theta, sp)
    noise = 1e-4 * np.cos(2 * np.pi * np.outer(np.arange(1, 6), sp.alpha) + rng.uniform(0, 6, (5, 1))).sum(0)
    perturbed = theta + noise
    assert abs(geometry.closure_defect(perturbed)) > 1e-6
    projected, before = geometry.project_closed(perturbed, sp, target)
    assert abs(geometry.closure_defect(projected)) < 1e-14
    assert geometry.enclosed_area(projected, sp) == pytest.approx(target, rel=1e-13)
    assert before != pytest.approx(target, rel=1e-9)
    assert np.abs(projected - perturbed).max() < 1e-3        # a small correction


def test_area_gradient_is_the_derivative_of_the_discrete_area(rng):
    N = 64
    sp = Spectral(N, REFERENCE_LENGTH)
    a, b = geometry.ellipse_for_excess_length(REFERENCE_LENGTH, 0.94)
    theta = geometry.ellipse_equal_arclength(a, b, N)[1] + 1e-3 * np.cos(6 * np.pi * sp.alpha)
    e = np.exp(1j * theta)
    gradient = geometry.area_gradient(e, sp.antiderivative_complex(e, 0.0), sp)
    h = 1e-6
    for _ in range(3):            # random directions: neither closing nor area-preserving
        v = rng.standard_normal(N)
        fd = (geometry.enclosed_area(theta + h * v, sp) - geometry.enclosed_area(theta - h * v, sp)) / (2 * h)
        assert gradient @ v == pytest.approx(fd, rel=1e-7, abs=1e-12)


def test_projection_keeps_a_circle_and_closes_it():
    sp = Spectral(32, REFERENCE_LENGTH)
    circle = 2 * np.pi * sp.alpha
    area = geometry.enclosed_area(circle, sp)
    projected, before = geometry.project_closed(circle + 1e-9 * np.sin(2 * np.pi * sp.alpha), sp, area)
    assert abs(geometry.closure_defect(projected)) < 1e-15
    assert geometry.enclosed_area(projected, sp) == pytest.approx(area, rel=1e-13)


# --- the smoothed start (physics.initial_shape = "smoothed", SPEC section 7) ------------------------

def _crosses_itself(z: np.ndarray) -> bool:
    """Whether the closed polygon through z has two non-adjacent edges that cross."""
    n = z.size
    p, r = z[:, None], (np.roll(z, -1) - z)[:, None]
    q, s = p.T, r.T
    cross = lambda u, v: (np.conj(u) * v).imag           # noqa: E731
    with np.errstate(divide="ignore", invalid="ignore"):
        t = cross(q - p, s) / cross(r, s)
        u = cross(q - p, r) / cross(r, s)
    i, j = np.nonzero((t > 0) & (t < 1) & (u > 0) & (u < 1))
    return bool(np.any(np.abs((i - j + n // 2) % n - n // 2) > 1))


@pytest.mark.parametrize("N", [64, 128])
@pytest.mark.parametrize("delta, ellipse_tip, smoothed_tip", [(0.94, 10.4, 6.2), (2.30, 26.0, 8.1)])
def test_smoothed_start_keeps_the_excess_length_and_blunts_the_tips(N, delta, ellipse_tip, smoothed_tip):
    # the tip curvatures of the two starts as the authors' code (under Octave) gives them: 26.0 -> 8.1
    # at Delta = 2.3, 10.4 -> 6.2 at Delta = 0.94 (a transcription of their initial set-up gives 8.1367
    # and 6.2109 at N = 128 and 256, and the same tangent angle as here to 3e-10)
    a, b = geometry.ellipse_for_excess_length(REFERENCE_LENGTH, delta)
    assert a / b**2 == pytest.approx(ellipse_tip, rel=0.01)          # the ellipse's tip (not resolved at N = 128)
    solver = make_solver(N=N, psi_bar=0.48, excess_length=delta, initial_shape="smoothed")
    start = solver.initial_state()
    area = geometry.enclosed_area(start.theta + solver.sp.circle_angle, solver.sp)
    assert geometry.excess_length(area, REFERENCE_LENGTH) == pytest.approx(delta, abs=1e-10)
    assert solver.initial_tails[0] < 1e-14                                # resolved already at N = 64
    smoothed = solver.shape(start)
    assert smoothed.curvature.max() == pytest.approx(smoothed_tip, rel=0.01)
    assert geometry.length_of(smoothed.z, solver.sp) == pytest.approx(REFERENCE_LENGTH, rel=1e-12)
    assert smoothed.curvature.min() < 0 if delta > 2 else smoothed.curvature.min() > 0   # concave flanks at 2.3


def test_smoothed_start_has_its_nodes_equally_spaced_in_arclength():
    # from the positions alone: their trigonometric interpolant, 16 times finer, has speed |dz/dalpha| = L
    solver = make_solver(N=64, psi_bar=0.48, excess_length=2.3, initial_shape="smoothed")
    z = solver.shape(solver.initial_state()).z
    fine = 16 * z.size
    spectrum = np.zeros(fine, complex)
    k = np.fft.fftfreq(z.size, 1 / z.size).astype(int)
    spectrum[k] = np.fft.fft(z) * 16
    speed = np.abs(np.fft.ifft(2j * np.pi * np.fft.fftfreq(fine, 1 / fine) * spectrum))
    assert np.abs(speed - REFERENCE_LENGTH).max() < 1e-10 * REFERENCE_LENGTH


def test_smoothed_start_keeps_the_low_modes_of_the_ellipse_rescaled():
    # modes 0-2 of the tangent angle's excess kept, 3-4 halved, the rest dropped, all scaled by one c > 1
    N = 64
    a, b = geometry.ellipse_for_excess_length(REFERENCE_LENGTH, 2.3)
    alpha = np.arange(N) / N
    smoothed = np.fft.rfft(geometry.smoothed_ellipse(a, b, N) - np.pi / 2 - 2 * np.pi * alpha) / N
    ellipse = geometry.ellipse_angle_modes(a, b)[4:]                       # k = 0..4
    assert np.abs(smoothed[5:]).max() < 1e-15
    assert np.abs(smoothed[[0, 1, 3]]).max() < 1e-15 and np.abs(ellipse[[0, 1, 3]]).max() < 1e-15  # odd, even modes
    c = smoothed[2] / ellipse[2]
    assert c.real == pytest.approx(1.1408, abs=1e-4) and abs(c.imag) < 1e-12
    assert smoothed[4] / ellipse[4] == pytest.approx(c / 2, rel=1e-12)
    # the same continuous curve at every N: the nodes of N = 64 are every other node of N = 128
    assert np.abs(geometry.smoothed_ellipse(a, b, 2 * N)[::2] - geometry.smoothed_ellipse(a, b, N)).max() < 1e-14


def test_smoothed_start_is_refused_where_it_would_cross_itself():
    sp = Spectral(512, REFERENCE_LENGTH, backend="numpy")
    for delta, crosses in ((7.76, False), (7.78, True)):              # the flanks touch at Delta = 7.7708
        a, b = geometry.ellipse_for_excess_length(REFERENCE_LENGTH, delta)
        z = sp.antiderivative_complex(np.exp(1j * geometry.smoothed_ellipse(a, b, sp.N)), 0.0)
        assert _crosses_itself(z) is crosses
    Physics(excess_length=7.77, initial_shape="smoothed")
    with pytest.raises(ConfigError, match="smoothed start crosses itself beyond 7.77"):
        Physics(excess_length=7.78, initial_shape="smoothed")
    Physics(excess_length=7.78)                                           # the ellipse is fine
    with pytest.raises(ConfigError, match="initial_shape = 'round'"):
        Physics(initial_shape="round")


def test_smoothed_circle_is_the_circle():
    a, b = geometry.ellipse_for_excess_length(REFERENCE_LENGTH, 0.0)
    alpha = np.arange(32) / 32
    assert np.abs(geometry.smoothed_ellipse(a, b, 32) - np.pi / 2 - 2 * np.pi * alpha).max() < 1e-15
