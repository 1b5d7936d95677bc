"""What one rank holds in memory at each N -> BENCHMARKS.md (``make bench``) and the model that
``hpcves campaign --plan --slurm`` asks memory by (run/timing.py ``rank_bytes``).

Each measurement is a fresh process that does what a campaign rank does for one case: imports
hpcves, runs a case (compiled engine, samples and snapshots written to a scratch file) for STEPS
steps, and reports its peak resident set (``ru_maxrss``). lambda = 1 and lambda = 4 (the GMRES
workspace of a viscosity contrast) at each N, with numba's cache filled and, at the smallest and
largest N, with an empty one (the engine compiled in the process: a cluster's first job); the table
gives the peak and the model base (+ compiling) + slope N^2 that run/timing.py carries
(``rank_bytes``), and how far each measurement lies from it.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_solver import machine  # noqa: E402
from hpcves.run.timing import rank_bytes  # noqa: E402
from report import replace_section  # noqa: E402

SIZES = (64, 128, 256, 512, 1024, 2048)
RATIOS = (1.0, 4.0)
STEPS = 30
HEADING = "Memory of a rank"

CHILD = """
import json, resource, sys, tempfile
from pathlib import Path
from hpcves.model.params import Case, Numerics, Physics, RunControl
from hpcves.run.casefile import create_case_file, run_file
N, ratio, steps = int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
case = Case(Physics(psi_bar=0.3, shear_rate=40.0, viscosity_ratio=ratio),
            Numerics(N=N, dt=1e-4),
            RunControl(t_end=(steps + 2) * 1e-4, sample_interval=1e-4, snapshot_interval=1e-4,
                       checkpoint_interval=10 * 1e-4, max_spectral_tail=1.0))
with tempfile.TemporaryDirectory() as scratch:
    outcome = run_file(create_case_file(Path(scratch) / "m.h5", case), resume=False, max_steps=steps)
print(json.dumps({"steps": outcome.steps, "rss": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}))
"""


def peak_rss(N: int, ratio: float, cache_dir: str | None = None) -> int:
    """The peak RSS of a fresh process running the case; ``cache_dir``: numba's cache there (an empty
    one: the engine is compiled in the process)."""
    env = dict(os.environ, **({"NUMBA_CACHE_DIR": cache_dir} if cache_dir else {}))
    out = subprocess.run([sys.executable, "-c", CHILD, str(N), str(ratio), str(STEPS)], capture_output=True,
                         text=True, check=True, env=env)
    return json.loads(out.stdout.strip().splitlines()[-1])["rss"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="*", default=SIZES)
    parser.add_argument("--out", type=Path, help="replace this section of the file (BENCHMARKS.md)")
    args = parser.parse_args()
    peak_rss(args.sizes[0], 1.0)                       # numba's cache filled for the cached rows
    rows = []
    for compiling in (False, True):
        for N in (args.sizes if not compiling else (args.sizes[0], args.sizes[-1])):
            for ratio in RATIOS:
                with tempfile.TemporaryDirectory() as empty:
                    rss = peak_rss(N, ratio, empty if compiling else None)
                model = rank_bytes(N, ratio != 1.0, compiling)
                rows.append((N, ratio, compiling, rss, model))
                print(f"N = {N:5d}, lambda = {ratio:g}, {'compiling' if compiling else 'cached'}: peak "
                      f"{rss / 2**20:8.1f} MiB, model {model / 2**20:8.1f} MiB ({model / rss:.2f} x)", flush=True)
    lines = [f"## {HEADING}", "",
             f"Measured {datetime.date.today()} on {machine()} (`bench/bench_memory.py`): the peak resident set "
             f"of a fresh process that runs one case for {STEPS} steps (compiled engine, writing samples and "
             "snapshots), what a campaign rank holds; and `run/timing.py rank_bytes`, the model that "
             "`--plan --slurm` asks memory by.", "",
             "| N | lambda | engine | peak RSS (MiB) | rank_bytes (MiB) | model / measured |",
             "|---|---|---|---|---|---|"]
    lines += [f"| {N} | {ratio:g} | {'compiled in the process' if compiling else 'from numba cache'} | "
              f"{rss / 2**20:.0f} | {model / 2**20:.0f} | {model / rss:.2f} |"
              for N, ratio, compiling, rss, model in rows]
    lines += ["", "`--plan --slurm` asks `--mem-per-cpu` = 1.25 x rank_bytes at the study's largest N, "
              "compiling included (a cluster's first job compiles the engine on every rank)."]
    if args.out:
        replace_section(args.out, HEADING, "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
