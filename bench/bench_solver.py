"""Solver benchmarks -> BENCHMARKS.md (``make bench``).

1. Milliseconds per time step at N = 64, 128, 256 on one core (medians of
   repeated blocks; the machine is shared, so medians and ratios from one run).
2. Where the time goes at N = 128 (each section timed on its own, medians).
3. The FFT backend behind the choice of pre-planned FFTW, and the tension
   matrix by 2-D FFT (the method before its closed form) for comparison.
4. The largest dt at N = 128 for which psi_bar = 0.3, S = 80, Delta = 0.194 runs
   to t = 1 with the period of theta within 1 % of a run at dt/4.
"""
from __future__ import annotations

import argparse
import datetime
import os
import platform
import statistics
import sys
import time

import numpy as np
import scipy
from scipy.linalg import lapack

from hpcves.analysis.periodicity import crossing_period
from hpcves.model import geometry
from hpcves.model.flow import cholesky_solve
from hpcves.model.forces import bending_force
from hpcves.model.params import Case, Numerics, Physics, RunControl
from hpcves.numerics.spectral import Spectral
from hpcves.run.runner import one_thread
from hpcves.solver.timestepping import Solver

one_thread()          # BLAS and OpenMP at one thread in this process and its workers (threadpoolctl)


def machine() -> str:
    cpu = "unknown CPU"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import pyfftw

    return (f"{platform.node()} -- {cpu}, {os.cpu_count()} cores visible, one used; "
            f"Python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
            f"pyfftw {pyfftw.__version__}; OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}")


def median_time(func, repeats=9, inner=1):
    func()
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(inner):
            func()
        samples.append((time.perf_counter() - t0) / inner)
    return statistics.median(samples), min(samples), max(samples)


def make(N, dt=1e-3, **physics):
    return Solver(Case(Physics(**physics), Numerics(N=N, dt=dt), RunControl(t_end=1.0)))


def step_timings():
    rows = []
    for label, physics in (("two-phase (psi_bar = 0.3, S = 80)", dict(psi_bar=0.3, shear_rate=80.0)),
                           ("homogeneous (psi_bar = 0, S = 10)", dict(psi_bar=0.0, shear_rate=10.0))):
        for N in (64, 128, 256):
            solver = make(N, **physics)
            state = solver.initial_state()
            for _ in range(40):                      # past the start-up steps
                state, _, _ = solver.step(state)
            holder = [state]

            def block(steps=50):
                s = holder[0]
                for _ in range(steps):
                    s, _, _ = solver.step(s)
                holder[0] = s

            med, lo, hi = median_time(block, repeats=7)
            rows.append((label, N, 1e3 * med / 50, 1e3 * lo / 50, 1e3 * hi / 50))
    return rows


class FFTBothSides:
    """T = D_s K D_s for a stack of N x N matrices by one 2-D real FFT: the way the tension
    matrix was formed before its closed form (StokesSLP.constraint_matrix), kept to compare.

    (K D)_ij = -(d/ds along j), so the two axes get factors i k and -i k'.
    """

    def __init__(self, sp: Spectral, n_stack: int = 3, backend: str = "fftw"):
        N = sp.N
        k_row = sp.kc.copy()
        k_row[N // 2] = 0.0
        self._symbol = k_row[:, None] * sp.ik.imag[None, :]
        self._N = N
        shape = (n_stack, N, N)
        if backend == "fftw":
            import pyfftw

            self.input = pyfftw.empty_aligned(shape, dtype="float64")
            spectrum = pyfftw.empty_aligned((n_stack, N, N // 2 + 1), dtype="complex128")
            self._spectrum = spectrum
            output = pyfftw.empty_aligned(shape, dtype="float64")
            self._forward = pyfftw.FFTW(self.input, spectrum, axes=(1, 2), flags=("FFTW_ESTIMATE",))
            self._backward = pyfftw.FFTW(spectrum, output, axes=(1, 2), direction="FFTW_BACKWARD",
                                         flags=("FFTW_ESTIMATE", "FFTW_DESTROY_INPUT"))
        else:
            self.input = np.empty(shape)
            self._forward = None

    def __call__(self) -> np.ndarray:
        if self._forward is None:
            return np.fft.irfft2(self._symbol * np.fft.rfft2(self.input), s=(self._N, self._N))
        self._forward()
        self._spectrum *= self._symbol
        return self._backward()

    def constraint_matrix(self, blocks, tangent):
        """A = -sum_ab diag(t_a) T_ab diag(t_b), ``blocks`` = (G_xx, G_xy, G_yy)."""
        self.input[...] = blocks
        T_xx, T_xy, T_yy = self()
        c, s = tangent.real, tangent.imag
        return -(np.outer(c, c) * T_xx + np.outer(s, s) * T_yy + (np.outer(c, s) + np.outer(s, c)) * T_xy)


def section_timings(N=128):
    solver = make(N, psi_bar=0.3, shear_rate=80.0)
    state = solver.initial_state()
    for _ in range(40):
        state, _, _ = solver.step(state)
    sp, flow, phys = solver.sp, solver.flow, solver.case.physics
    shape = solver.shape(state)
    psi_nodes = state.psi
    psi_s = sp.ds(psi_nodes)
    slp = flow.slp
    blocks = slp.assemble(shape.z, shape.tangent).copy()
    cartesian = np.array(slp.cartesian(blocks))
    f_b = bending_force(shape.curvature, psi_nodes, psi_s, shape.tangent, phys, sp)
    A = slp.constraint_matrix(shape.tangent, shape.curvature).copy()
    by_fft = FFTBothSides(sp)
    difference = np.abs(by_fft.constraint_matrix(cartesian, shape.tangent) - A).max() / np.abs(A).max()
    factor = lapack.dpotrf(A.T.copy(order="F"), lower=1)[0]
    rates = solver.rates(state)
    work = np.empty((N, N))
    parts = [
        ("Stokeslet assembly (3 N x N blocks, log)", lambda: slp.assemble(shape.z, shape.tangent)),
        ("tension matrix, closed form", lambda: slp.constraint_matrix(shape.tangent, shape.curvature, out=work)),
        ("tension matrix by 2-D FFT of the blocks (not used; "
         f"differs by {difference:.0e} relative)", lambda: by_fft.constraint_matrix(cartesian, shape.tangent)),
        ("Cholesky factorisation (dpotrf, Fortran view, lower)", lambda: lapack.dpotrf(A.T, lower=1, overwrite_a=0)),
        ("Cholesky factorisation of the C-ordered array (not used)", lambda: lapack.dpotrf(A, lower=1, overwrite_a=0)),
        ("Cholesky solve (two dtrsv)", lambda: cholesky_solve(factor, psi_s)),
        ("single-layer matvec", lambda: slp.apply(blocks, f_b)),
        ("Cahn-Hilliard linearized solve (circulant + low rank)", lambda: solver.cahn_hilliard.solve_linearized(
            state.psi, 1500.0, state.psi.copy(), -15.0)),
        ("one 1-D FFT derivative (pair)", lambda: sp.ds(psi_nodes)),
        ("membrane flow (assembly, tension with refinement, velocity)",
         lambda: flow.solve(shape, psi_nodes, psi_s)),
        ("whole right-hand side (rates)", lambda: solver.rates(state)),
        ("update + projections (step given rates)", lambda: solver.step(state, rates)),
        ("whole step", lambda: solver.step(state)),
    ]
    return [(name, 1e6 * median_time(func, repeats=15, inner=20)[0]) for name, func in parts]


def fft_backends(N=128):
    rows = []
    for backend in ("numpy", "fftw"):
        sp = Spectral(N, 2.6442, backend=backend)
        x = np.random.default_rng(0).standard_normal(N)
        both = FFTBothSides(sp, 3, backend=backend)
        both.input[...] = np.random.default_rng(1).standard_normal((3, N, N))
        rows.append((backend, 1e6 * median_time(lambda: sp.ds(x), repeats=15, inner=200)[0],
                     1e6 * median_time(both, repeats=15, inner=10)[0]))
    return rows


def theta_period(dt, N=128, T=1.0, t_start=0.3):
    solver = make(N, dt=dt, psi_bar=0.3, shear_rate=80.0, excess_length=0.194)
    state = solver.initial_state()
    every = max(1, round(1e-3 / dt))
    t, theta = [], []
    try:
        for n in range(round(T / dt) + 1):
            if n % every == 0:
                shape = solver.shape(state)
                t.append(n * dt)
                theta.append(geometry.moments(shape.z, shape.normal, solver.sp.length).inclination)
            state, _, _ = solver.step(state)
    except ArithmeticError as exc:
        return None, np.nan, f"failed: {exc}"
    t, theta = np.array(t), np.array(theta)
    period = crossing_period(t, theta, t_start=t_start)
    cycles = (t >= period.start) & (t < period.end)            # whole cycles only
    return period, float(theta[cycles].mean()) if cycles.any() else np.nan, ""


def largest_dt(candidates=(8e-3, 6e-3, 5e-3, 4e-3, 3e-3, 2e-3, 1.5e-3, 1e-3)):
    """Rows (dt, period, period at dt/4, relative difference, mean-theta difference, note)."""
    rows = []
    for dt in candidates:
        p, mean, note = theta_period(dt)
        ref, mean_ref, note_ref = theta_period(dt / 4)
        if p is None or ref is None or not np.isfinite(p.period):
            rows.append((dt, np.nan, np.nan if ref is None else ref.period, np.nan, np.nan,
                         note or note_ref or "no period"))
            continue
        rel = abs(p.period - ref.period) / ref.period
        rows.append((dt, p.period, ref.period, rel, mean - mean_ref, ""))
    ok = [row[0] for row in rows if np.isfinite(row[3]) and row[3] <= 0.01]
    return rows, (max(ok) if ok else None)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default="BENCHMARKS.md")
    args = parser.parse_args(argv)
    start = time.time()
    print("timing steps ...", file=sys.stderr)
    steps = step_timings()
    print("timing sections ...", file=sys.stderr)
    sections = section_timings()
    print("FFT backends ...", file=sys.stderr)
    backends = fft_backends()
    print("largest dt (about half a minute) ...", file=sys.stderr)
    dt_rows, dt_max = largest_dt()

    lines = ["# Benchmarks", "",
             f"Run {datetime.datetime.now():%Y-%m-%d %H:%M} by `make bench` ({time.time() - start:.0f} s) on: "
             + machine() + ".", "",
             "Shared machine: medians of repeated blocks; compare ratios within one run.", "",
             "## Milliseconds per time step (one core)", "",
             "| case | N | median ms/step | min | max |", "| --- | ---: | ---: | ---: | ---: |"]
    lines += [f"| {label} | {N} | {med:.3f} | {lo:.3f} | {hi:.3f} |" for label, N, med, lo, hi in steps]
    two_phase_128 = [m for label, N, m, _, _ in steps if N == 128 and label.startswith("two")][0]
    lines += ["", f"Target: 0.5 ms per step at N = 128. Measured (two-phase): **{two_phase_128:.2f} ms** -- "
              + ("met." if two_phase_128 <= 0.5 else "not met; see where the time goes below."), "",
              "## Where the time goes (N = 128, two-phase, each part timed alone, microseconds)", "",
              "| part | median us |", "| --- | ---: |"]
    lines += [f"| {name} | {us:.1f} |" for name, us in sections]
    lines += ["", "## FFT backend (N = 128, microseconds)", "",
              "| backend | 1-D derivative (forward + inverse) | D G D of a 3 x N x N stack |", "| --- | ---: | ---: |"]
    lines += [f"| {b} | {d1:.1f} | {d2:.1f} |" for b, d1, d2 in backends]
    lines += ["", "## Largest time step (N = 128, psi_bar = 0.3, S = 80, Delta = 0.194, t = 1)", "",
              "Period of theta(t) from its mid-line crossings for t in [0.3, 1], against a run at dt/4 "
              "(theta sampled every 1e-3 or every step, whichever is coarser); also the difference of "
              "the mean inclination over the whole cycles in that window.", "",
              "| dt | period | period at dt/4 | relative difference | mean theta difference (rad) | note |",
              "| ---: | ---: | ---: | ---: | ---: | --- |"]
    def cell(value, fmt):
        return format(value, fmt) if np.isfinite(value) else "--"

    lines += [f"| {dt:g} | {cell(p, '.5f')} | {cell(r, '.5f')} | {cell(rel, '.2%')} | {cell(dm, '.1e')} | {note} |"
              for dt, p, r, rel, dm, note in dt_rows]
    met = dt_max is not None and dt_max >= 1e-3
    lines += ["", f"Largest dt within 1 %: **{dt_max if dt_max is not None else 'none'}** (target: >= 1e-3, "
              + ("met" if met else "not met") + "; the published method used 1e-5).", ""]
    with open(args.out, "w") as fh:
        fh.write("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
