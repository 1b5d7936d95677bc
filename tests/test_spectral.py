import numpy as np
import pytest

from hpcves.numerics.spectral import Spectral

L = 2.6442


@pytest.mark.parametrize("backend", ["fftw", "numpy"])
def test_derivatives_of_trigonometric_polynomials_are_exact(backend):
    sp = Spectral(32, L, backend=backend)
    s = L * sp.alpha
    k = 2 * np.pi * 3 / L
    f = np.sin(k * s) + 0.5 * np.cos(2 * k * s)
    assert np.allclose(sp.ds(f), k * np.cos(k * s) - k * np.sin(2 * k * s), atol=1e-12)
    assert np.allclose(sp.ds2(f), -k**2 * np.sin(k * s) - 2 * k**2 * np.cos(2 * k * s), atol=1e-11)


@pytest.mark.parametrize("backend", ["fftw", "numpy"])
def test_antiderivative_inverts_the_derivative(backend):
    sp = Spectral(64, L, backend=backend)
    z = (1.0 + 0.2 * np.cos(2 * np.pi * sp.alpha)) * np.exp(2j * np.pi * sp.alpha) + 0.3 - 0.1j
    w = sp.ds_complex(z)
    assert np.allclose(sp.antiderivative_complex(w, z.mean()), z, atol=1e-13)


def test_shift_and_interpolation_agree_with_the_function():
    sp = Spectral(32, L)
    f = lambda a: np.cos(2 * np.pi * a) + 0.3 * np.sin(6 * np.pi * a)  # noqa: E731
    samples = f(sp.alpha)
    shifted = sp.fft.irfft(sp.shift_symbol(0.123) * sp.fft.rfft(samples))
    assert np.allclose(shifted, f(sp.alpha - 0.123), atol=1e-13)
    once, twice = sp.shift_symbols(0.0123)
    assert np.allclose(once, sp.shift_symbol(0.0123), rtol=0, atol=1e-15)
    assert np.allclose(twice, sp.shift_symbol(0.0246), rtol=0, atol=1e-15)
    points = np.array([0.01, 0.37, 0.999])
    assert np.allclose(sp.interpolate(samples, points), f(points), atol=1e-13)
    stacked = sp.interpolate(np.stack([samples, 2 * samples]), 0.37)
    assert stacked.shape == (2,) and np.isclose(stacked[1], 2 * f(0.37))


def test_transforms_never_write_into_their_inputs():
    """pyfftw adopts a suitably aligned input as its buffer and would later copy a
    strided input into it; the wrapper must copy instead (this once overwrote state)."""
    sp = Spectral(64, 2.0)
    first = np.random.default_rng(1).standard_normal(64)
    kept = first.copy()
    sp.ds(first)
    strided = np.random.default_rng(2).standard_normal(128)[::2]
    sp.ds(strided)
    sp.fft.irfft(sp.fft.rfft(np.random.default_rng(3).standard_normal(130)[1:-1:2].copy()))
    assert np.array_equal(first, kept)


@pytest.mark.parametrize("n", [96, 128, 200])
def test_transforms_give_the_bits_of_the_fftw_call(n):
    """The wrapper runs plans by execute() and scales inverses itself: the same bits
    as FFTW.__call__ (which bitwise restarts and the reference runs were made with)."""
    fft = Spectral(n, 2.0).fft
    rng = np.random.default_rng(n)
    x = rng.standard_normal(n)
    z = x + 1j * rng.standard_normal(n)
    for name, data in (("rfft", x), ("irfft", np.fft.rfft(x)), ("fft", z), ("ifft", z)):
        plan = fft.plans[name]
        mine = getattr(fft, name)(data)
        plan.input_array[...] = data                 # (a c2r transform may destroy its input)
        assert np.array_equal(mine, plan().copy()), name


def test_displacement_finds_a_subgrid_shift():
    sp = Spectral(128, 2.6442)
    def pattern(a):
        return 0.5 + 0.5 * np.tanh(8 * np.cos(2 * np.pi * a)) + 0.1 * np.sin(6 * np.pi * a)

    for shift in (0.0, 1e-5, 0.0123, -0.031, 0.1):
        assert sp.displacement(pattern(sp.alpha - shift), pattern(sp.alpha)) == pytest.approx(shift, abs=1e-9)
    assert sp.displacement(np.ones(128), np.ones(128)) == 0.0
    # beyond the window the best shift inside it is returned, not a far one
    assert abs(sp.displacement(pattern(sp.alpha - 0.4), pattern(sp.alpha), window=0.125)) <= 0.125


@pytest.mark.parametrize("n", [16, 48, 64, 96, 128, 512])
def test_resample_is_bitwise_scipy_signal_resample_without_importing_it(n):
    from scipy import signal

    from hpcves.numerics.spectral import resample

    rng = np.random.default_rng(n)
    fields = rng.standard_normal((7, n))
    for N in {16, 32, 48, 64, 96, 128, 256, 384, 512, 1024} - {n}:        # the same size: a copy
        expected = np.array([signal.resample(row, N) for row in fields])
        assert np.array_equal(resample(fields, N), expected), (n, N)              # a stack, along its last axis
        assert np.array_equal(resample(fields[3], N), expected[3]), (n, N)
    z = fields[0] + 1j * fields[1]
    assert np.array_equal(resample(z, 2 * n), signal.resample(z.real, 2 * n) + 1j * signal.resample(z.imag, 2 * n))
    assert np.array_equal(resample(fields, n), fields) and resample(fields, n) is not fields
