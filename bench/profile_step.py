"""Where a time step's CPU goes, by class of code -> BENCHMARKS.md ("Throughput: the compiled step").

A child process steps the two-phase solver (psi_bar = 0.3, S = 80, fixed dt = 1e-3) of one tree
(PYTHONPATH; run from outside it) while ``perf record`` samples it for a few seconds; the samples'
shared objects and symbols are sorted into the classes of issue #41's table: numpy / numba dispatch
and allocation, the Python interpreter, malloc / memcpy, arithmetic (compiled code, BLAS/LAPACK,
FFT, libm, numpy's inner loops) and the rest. Needs Linux ``perf``.

    python bench/profile_step.py --tree . --N 64 128 [--engine numpy]
"""
from __future__ import annotations

import argparse
import collections
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = """
import sys, time
from hpcves.run.runner import one_thread
one_thread()
from hpcves.model.params import Case, Numerics, Physics, RunControl
from hpcves.solver.timestepping import Solver
N, engine, ready = int(sys.argv[1]), sys.argv[2], sys.argv[3]
case = Case(Physics(psi_bar=0.3, shear_rate=80.0), Numerics(N=N, dt=1e-3), RunControl(t_end=1e6))
solver = Solver(case) if engine == "default" else Solver(case, engine=engine)
state = solver.initial_state()
for _ in range(40):
    state, _, _ = solver.step(state)
open(ready, "w").close()
while True:
    state, _, _ = solver.step(state)
"""

ARITHMETIC = "arithmetic: compiled code, BLAS/LAPACK, FFT, libm, numpy's loops"
DISPATCH = "numpy / numba dispatch and allocation"
CLASSES = (DISPATCH, "Python interpreter", "malloc / memcpy", ARITHMETIC, "other (libc, kernel, loader)")
#: numpy's own arithmetic: its SIMD loops and inner kernels, by symbol
NUMPY_LOOPS = re.compile(r"AVX|avx|_simd|simd_|SSE|sse|FMA3|_loop|DOUBLE_|CDOUBLE_|npyv|_unary|_binary|log|exp|"
                         r"sqrt|sin|cos|dot|matmul|gemm|erfc|argmax|argmin|pairwise_sum")
KERNELS = ("[JIT]", "libscipy_openblas", "libopenblas", "_rocket_fft", "libfftw", "libm.so", "_flapack",
           "cython_lapack")


def classify(dso: str, symbol: str) -> str:
    if dso.startswith("libpython") or dso.startswith("python3"):
        return "Python interpreter"
    if dso.startswith("libc.so"):
        return ("malloc / memcpy" if re.search(r"malloc|free|memcpy|memmove|memset|_int_|realloc|calloc", symbol)
                else CLASSES[-1])
    if dso.startswith(("_multiarray_umath", "_special_ufuncs")):
        return ARITHMETIC if NUMPY_LOOPS.search(symbol) else DISPATCH
    if dso.startswith(("_nrt_python", "_dispatcher", "_helperlib")):
        return DISPATCH
    if dso.startswith(KERNELS):
        return ARITHMETIC
    return CLASSES[-1]


def profile(tree: Path, N: int, engine: str, seconds: float) -> dict:
    """{class: share in %} of the samples of ``seconds`` of steps."""
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    with tempfile.TemporaryDirectory() as folder:
        ready, data = Path(folder) / "ready", Path(folder) / "perf.data"
        child = subprocess.Popen([sys.executable, "-c", CHILD, str(N), engine, str(ready)], env=env, cwd=folder)
        try:
            deadline = time.monotonic() + 600                # a guard against a hang only
            while not ready.exists():
                if child.poll() is not None or time.monotonic() > deadline:
                    raise SystemExit(f"the stepping child ended or hung (N = {N})")
                time.sleep(0.1)
            subprocess.run(["perf", "record", "-q", "-F", "2000", "-p", str(child.pid), "-o", str(data), "--",
                            "sleep", str(seconds)], check=True, capture_output=True)
        finally:
            child.kill()
            child.wait()
        report = subprocess.run(["perf", "report", "-i", str(data), "--sort", "dso,sym", "--stdio",
                                 "--percent-limit", "0"], capture_output=True, text=True, check=True).stdout
    shares = collections.Counter()
    for line in report.splitlines():
        found = re.match(r"\s*([\d.]+)%\s+(\S+)\s+\[.\]\s+(.*)", line)
        if found:
            shares[classify(found.group(2), found.group(3).strip())] += float(found.group(1))
    total = sum(shares.values()) or 1.0
    return {c: 100.0 * shares[c] / total for c in CLASSES}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tree", type=Path, default=Path(__file__).resolve().parents[1])
    parser.add_argument("--N", type=int, nargs="+", default=[64, 128])
    parser.add_argument("--engine", default="default", help="compiled, numpy, or the tree's default")
    parser.add_argument("--seconds", type=float, default=4.0)
    args = parser.parse_args(argv)
    found = {N: profile(args.tree.resolve(), N, args.engine, args.seconds) for N in args.N}
    print("| share of a step | " + " | ".join(f"N = {N}" for N in args.N) + " |")
    print("| --- |" + " ---: |" * len(args.N))
    for c in CLASSES:
        print(f"| {c} | " + " | ".join(f"{found[N][c]:.0f} %" for N in args.N) + " |")
    return found


if __name__ == "__main__":
    main()
