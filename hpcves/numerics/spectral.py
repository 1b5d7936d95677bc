"""Fourier pseudo-spectral calculus on the periodic material coordinate.

A field f(alpha) is sampled at alpha_j = j/N, j = 0..N-1, alpha in [0, 1); the
arclength is s = L alpha (the membrane is inextensible, so L is constant and
d/ds = (1/L) d/dalpha). Odd derivatives drop the Nyquist mode, even ones keep
it, so derivatives of real fields stay real.

Transforms are pre-planned FFTW objects (:mod:`pyfftw.builders`) for the few
shapes a solver uses: at N ~ 100 the cost of a transform called from Python
is mostly call overhead, where a planned FFTW object is 3-5x cheaper than
:mod:`numpy.fft` (BENCHMARKS.md). Plans use FFTW_ESTIMATE, so they -- and
every bit of every result -- are the same in every run, which bitwise
restarts rely on. ``backend="numpy"`` gives the same API on numpy.fft.

FFTW objects return their internal output buffer; every method here returns
a fresh array.
"""
from __future__ import annotations

import numpy as np


class _NumpyFFT:
    name = "numpy"

    def __init__(self, n: int):
        self.n = n

    def rfft(self, x):
        return np.fft.rfft(x)

    def irfft(self, x):
        return np.fft.irfft(x, n=self.n)

    def fft(self, x):
        return np.fft.fft(x)

    def ifft(self, x):
        return np.fft.ifft(x)

    def multiply(self, x, symbol, mode0=None):
        """irfft(symbol * rfft(x)), mode 0 of the product set to ``mode0`` if given."""
        return np.fft.irfft(_set_mode0(symbol * np.fft.rfft(x), mode0), n=self.n)

    def multiply_complex(self, x, symbol, mode0=None):
        """ifft(symbol * fft(x)), mode 0 of the product set to ``mode0`` if given."""
        return np.fft.ifft(_set_mode0(symbol * np.fft.fft(x), mode0))


def _set_mode0(spectrum, mode0):
    if mode0 is not None:
        spectrum[0] = mode0
    return spectrum


class _FFTW:
    """Planned FFTW transforms of length n.

    The input is always copied into the plan's own buffer. Passing it to
    FFTW.__call__ instead would let pyfftw *adopt* a suitably aligned caller
    array as its input buffer (update_arrays) and later copy a misaligned or
    strided input *into that caller's array* -- silently overwriting it.
    Plans are run by FFTW.execute, without __call__'s checks, and inverse
    transforms scaled by 1/n as __call__ scales them (by its
    _normalisation_scaling = 1/float(n)): the same bits (tests/test_spectral.py),
    0.05-0.2 us less per transform timed alone at N = 128, 13 us less per time
    step. A Fourier multiplier passes the spectrum from the forward plan's output
    straight into the inverse plan's input (the arithmetic of irfft(symbol * rfft(x))).
    """

    name = "fftw"

    def __init__(self, n: int):
        import pyfftw
        import pyfftw.builders as fb

        kw = dict(planner_effort="FFTW_ESTIMATE", threads=1)
        real = pyfftw.empty_aligned(n, dtype="float64")
        cplx = pyfftw.empty_aligned(n, dtype="complex128")
        half = pyfftw.empty_aligned(n // 2 + 1, dtype="complex128")
        self.n = n
        self.plans = {"rfft": fb.rfft(real, **kw), "irfft": fb.irfft(half, n=n, **kw),
                      "fft": fb.fft(cplx, **kw), "ifft": fb.ifft(cplx, **kw)}
        scale = 1 / float(n)                                  # what FFTW.__call__ scales inverses by
        plans = self.plans
        self.rfft = _transform(plans["rfft"])
        self.fft = _transform(plans["fft"])
        self.irfft = _transform(plans["irfft"], scale)
        self.ifft = _transform(plans["ifft"], scale)
        self.multiply = _multiplier(plans["rfft"], plans["irfft"], scale)
        self.multiply_complex = _multiplier(plans["fft"], plans["ifft"], scale)


def _transform(plan, scale=None):
    """x -> the plan's transform of x, scaled by ``scale`` if given (closures: one Python call)."""
    buffer, execute, output = plan.input_array, plan.execute, plan.output_array

    def unscaled(x):
        buffer[...] = x
        execute()
        return output.copy()

    def scaled(x):
        buffer[...] = x
        execute()
        return np.multiply(output, scale)

    return unscaled if scale is None else scaled


def _multiplier(forward, inverse, scale):
    """(x, symbol, mode0=None) -> inverse(symbol * forward(x)), mode 0 of the product set to ``mode0`` if given."""
    buffer, execute, output = forward.input_array, forward.execute, forward.output_array
    buffer_inverse, execute_inverse, output_inverse = inverse.input_array, inverse.execute, inverse.output_array

    def multiply(x, symbol, mode0=None):
        buffer[...] = x
        execute()
        np.multiply(symbol, output, out=buffer_inverse)
        if mode0 is not None:
            buffer_inverse[0] = mode0
        execute_inverse()
        return np.multiply(output_inverse, scale)

    return multiply


def make_fft(n: int, backend: str = "fftw"):
    if backend == "numpy":
        return _NumpyFFT(n)
    if backend == "fftw":
        return _FFTW(n)
    raise ValueError(f"unknown FFT backend {backend!r} (use 'fftw' or 'numpy')")


#: the modes whose share of a field's variation measures its resolution: the top third
TAIL_FROM = 1.0 / 3.0


def spectral_tail(f_hat: np.ndarray, N: int, start: float = TAIL_FROM) -> float:
    """sqrt(sum_{m >= m0} |f_m|^2 / sum_{m >= 1} |f_m|^2), m0 = ceil(start N): the share of the top modes.

    ``f_hat`` is the rfft of N samples (modes 0 ... N/2); start = 1/3 takes
    the top third of the band. 0 for a constant field. A resolved spectral
    solution has a share that falls exponentially with N (docs/numerics.md).
    """
    power = np.abs(f_hat[1:]) ** 2
    total = float(power.sum())
    if total <= 0.0:
        return 0.0
    return float(np.sqrt(power[int(np.ceil(start * N)) - 1:].sum() / total))


def resolution_needed(f_hat: np.ndarray, N: int, target: float, largest: int = 8, sizes=None) -> int:
    """The smallest N' (a multiple of 16, or one of ``sizes``; at most ``largest`` N) at which this
    field's tail would be ``target`` or less, extrapolating its spectrum.

    log |f_m|^2 is fitted by a straight line over the upper part of the band
    (N/6 <= m < N/2: the exponential decay of an analytic field); modes up to
    N/2 keep their values, higher ones follow the line, and the tail share of
    N' is computed from that spectrum. 2 N if the spectrum does not decay.
    """
    if spectral_tail(f_hat, N) <= target:
        return N
    candidates = (range(16 * (N // 16 + 1), largest * N + 1, 16) if sizes is None
                  else [n for n in sizes if N < n <= largest * N])
    power = np.abs(f_hat) ** 2
    m = np.arange(power.size)
    fit = (m >= N / 6.0) & (m < N // 2) & (power > 0)
    if fit.sum() < 2:
        return 2 * N
    slope, intercept = np.polyfit(m[fit], np.log(power[fit]), 1)
    if not slope < 0:
        return 2 * N
    for candidate in candidates:
        modes = np.arange(candidate // 2 + 1)
        extended = np.exp(intercept + slope * modes)
        extended[: power.size] = power[: candidate // 2 + 1]
        if spectral_tail(np.sqrt(extended), candidate) <= target:
            return candidate
    return largest * N


def fft_sizes(smallest: int, largest: int) -> tuple[int, ...]:
    """The grid sizes from ``smallest`` to ``largest`` that a run with N adapting may take: 2^k and
    3 2^k (>= 16; FFTW's fastest sizes, and steps of 4/3 and 3/2 between neighbours)."""
    sizes = sorted({m * 2**k for m in (2, 3) for k in range(3, 13)})
    return tuple(n for n in sizes if smallest <= n <= largest)


def resample(f: np.ndarray, N: int) -> np.ndarray:
    """The trigonometric interpolant of the periodic samples ``f`` at N equispaced nodes (f's
    spectrum padded with zeros or truncated), along the last axis. Exact for a field whose modes
    lie below both Nyquist modes; growing and shrinking back returns f to round-off. A copy of f
    when N is its size. Complex samples: their real and imaginary parts, each so resampled.

    scipy.signal.resample's arithmetic for real samples (rfft, the shared Nyquist mode halved when
    growing and doubled when shrinking, irfft scaled by N / n), bitwise its results
    (tests/test_spectral.py), without importing scipy.signal: that import costs a process ~0.7 s.
    """
    if np.iscomplexobj(f):
        return resample(f.real, N) + 1j * resample(f.imag, N)
    f = np.asarray(f, dtype=float)
    n = f.shape[-1]
    if n == N:
        return f.copy()
    m = min(N, n)
    spectrum = np.fft.rfft(f)[..., : m // 2 + 1]
    if m % 2 == 0:
        spectrum[..., m // 2] *= 2 if N < n else 0.5
    return np.fft.irfft(spectrum / (n / N), n=N)


def tail_on(f_hat: np.ndarray, N: int, M: int) -> float:
    """The spectral tail (:func:`spectral_tail`) the field of rfft ``f_hat`` (N samples) would have on
    M <= N nodes: its modes up to M/2 taken as the smaller grid's spectrum."""
    return spectral_tail(f_hat[: M // 2 + 1], M)


class Spectral:
    """Derivatives, antiderivatives and interpolation for N-periodic samples.

    Wavenumbers are in arclength units: k_m = 2 pi m / L.
    """

    def __init__(self, N: int, length: float, backend: str = "fftw"):
        if N % 2:
            raise ValueError("N must be even")
        self.N = N
        self.length = float(length)
        self.fft = make_fft(N, backend)
        m = np.arange(N // 2 + 1)
        self.k = 2.0 * np.pi * m / self.length                 # |k| for rfft modes
        self.ik = 1j * self.k
        self.ik[-1] = 0.0                                       # odd derivative: drop Nyquist
        self.k2 = -self.k**2                                    # (ik)^2 with Nyquist kept
        mc = np.fft.fftfreq(N, 1.0 / N)                        # full-FFT modes
        self.kc = 2.0 * np.pi * mc / self.length
        self.ikc = 1j * self.kc
        self.ikc[N // 2] = 0.0
        self._inv_ikc = np.zeros(N, dtype=complex)
        self._inv_ikc[self.ikc != 0] = 1.0 / self.ikc[self.ikc != 0]
        self.alpha = np.arange(N) / N
        self.circle_angle = 2.0 * np.pi * self.alpha            # tangent angle of a circle, 2 pi alpha
        m2pi = 2.0 * np.pi * m
        self._im2pi = 1j * m2pi
        self._m2pi_powers = np.array([m2pi, m2pi**2])
        self._lag_index = {}

    # -- real fields ------------------------------------------------------------
    def ds(self, f):
        """d f / ds."""
        return self.fft.multiply(f, self.ik)

    def ds2(self, f):
        """d^2 f / ds^2."""
        return self.fft.multiply(f, self.k2)

    def shift_symbol(self, a):
        """rfft multiplier that turns samples of f(alpha) into samples of f(alpha - a).

        Mode m gets e^{-2 pi i m a}; the Nyquist mode, whose sine part is not
        representable on the grid, gets cos(pi N a).
        """
        symbol = np.exp(-a * self._im2pi)
        symbol[-1] = np.cos(np.pi * self.N * a)
        return symbol

    def shift_symbols(self, a):
        """(shift_symbol(a), shift_symbol(2 a)), the second as the square of the first."""
        once = self.shift_symbol(a)
        twice = once * once
        twice[-1] = np.cos(2.0 * np.pi * self.N * a)
        return once, twice

    def project(self, f, keep):
        """f with its rfft modes multiplied by ``keep`` (a mask or filter)."""
        return self.fft.multiply(f, keep)

    def displacement(self, f, g, window: float = 0.125, spectra=None):
        """The shift a, |a| <= ``window``, for which f(alpha) ~ g(alpha - a).

        a maximises the cross-correlation R(a) = sum_j f(alpha_j) g(alpha_j - a)
        of the trigonometric interpolants (R is itself a trigonometric polynomial,
        with coefficients f_m conj(g_m)): the best grid point, the vertex of the
        parabola through it and its neighbours, then Newton on R' until a step is
        below 1e-5 (usually the first: the vertex is within ~1e-6 of a pattern
        moving by less than a grid spacing, and after a step d what remains is
        ~ d^2 R'''/(2 R''): 5e-16 after d = 1.6e-6 on a phase-treading pattern). The solver
        uses a as the velocity of a moving frame, where any value gives a
        consistent step: it needs to be near the pattern's shift, and a
        deterministic function of f and g.
        Returns 0 if f and g have no variation (nothing to align). ``spectra``
        may pass (rfft(f), rfft(g)) if the caller has them.
        """
        N = self.N
        f_hat, g_hat = spectra if spectra is not None else (self.fft.rfft(f), self.fft.rfft(g))
        q = f_hat * np.conj(g_hat)
        q[0] = 0.0
        q[-1] = 0.0                                  # the Nyquist mode has no phase to align
        R = self.fft.irfft(q)
        if window not in self._lag_index:
            reach = max(1, int(window * N))
            lags = np.arange(-reach, reach + 1)
            self._lag_index[window] = (lags, lags % N)
        lags, index = self._lag_index[window]
        best = int(np.argmax(R[index]))
        a = a_grid = lags[best] / N
        j = int(index[best])
        before, peak, after = R[j - 1], R[j], R[(j + 1) % N]
        if peak == 0.0 and not q.any():                  # f or g without variation: nothing to align
            return 0.0
        if before - 2.0 * peak + after < 0.0:            # start Newton at the parabola's vertex
            a += 0.5 * (before - after) / (before - 2.0 * peak + after) / N
        for _ in range(20):
            wave = q * np.exp(a * self._im2pi)
            _, slope, curvature, _ = (self._m2pi_powers @ wave.view(np.float64).reshape(-1, 2)).ravel().tolist()
            if curvature <= 0.0:                         # not at a maximum: keep the grid point
                break
            step = slope / curvature                     # Newton on R'(a), R' ~ -slope, R'' ~ -curvature
            a -= step
            if abs(step) < 1e-5:                         # quadratic: what remains is ~ step^2 R'''/R''
                break
        if not abs(a - a_grid) <= 1.0 / N:               # Newton left the grid point's bracket
            return float(a_grid)
        return float(a)

    # -- complex fields (positions z = x + i y) ---------------------------------
    def ds_complex(self, z):
        """d z / ds for a complex field."""
        return self.fft.multiply_complex(z, self.ikc)

    def antiderivative_complex(self, w, mean):
        """The periodic z with dz/ds = w and mean(z) = ``mean``.

        Requires mean(w) = 0 (a closed curve); the mean of w is ignored.
        """
        return self.fft.multiply_complex(w, self._inv_ikc, mode0=mean * self.N)

    # -- interpolation -----------------------------------------------------------
    def interpolate(self, f, alpha):
        """Trigonometric interpolant of samples f (..., N), real or complex, at points alpha.

        Returns shape (..., len(alpha)), or (...) for a scalar alpha.
        """
        scalar = np.ndim(alpha) == 0
        alpha = np.atleast_1d(np.asarray(alpha, dtype=float))
        fh = np.fft.fft(f, axis=-1) / self.N
        m = np.fft.fftfreq(self.N, 1.0 / self.N)
        basis = np.exp(2j * np.pi * np.outer(m, alpha))
        basis[self.N // 2] = np.cos(np.pi * self.N * alpha)     # Nyquist mode, real
        values = fh @ basis
        if not np.iscomplexobj(f):
            values = values.real
        return values[..., 0] if scalar else values

