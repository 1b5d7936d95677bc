"""A campaign of many tiny cases from end to end -> the "Campaigns at scale" table of BENCHMARKS.md.

One row per run: ``mpirun -n RANKS hpcves campaign`` of CASES tiny cases (N = 16, 10 steps; or a
``[refine]`` study whose stages add them) under an I/O mode, then ``hpcves status --json``,
``status --check`` and ``hpcves analyze``. Measured: the seconds until the file appears (its
creation), of the whole campaign, its cases per second after creation, the CPU seconds of rank 0
and the median of the other ranks (sampled from /proc every 0.2 s; under relay rank 0 writes for
everyone), the wall of each status and analyze and analyze's peak memory (``/usr/bin/time``), the
file's size; for ``[refine]`` the seconds rank 0 spends between stages per case it adds (from the
campaign's log).

    python bench/bench_scale.py --cases 500 5000 --ranks 8 --io relay mpio
    python bench/bench_scale.py --refine 3000 --ranks 2 --io mpio
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_creation import MPI_ENV

#: ten steps of N = 16: the cases are many and each is short
TEN_STEPS = """t_end = 0.01
[numerics]
N = 16
dt = 1e-3
[run]
max_spectral_tail = 1.0
sample_interval = 0.001
snapshot_interval = 0.005
checkpoint_interval = 0.005
"""
GRID = """
[campaign]
name = "scale"
output = "{output}"
""" + TEN_STEPS + """[sweep]
shear_rate = {{ linspace = [1, 100, {n}] }}
"""
# every point undecided after 10 steps: each refinement splits every cell to its tolerance
REFINE = """
[campaign]
name = "scale-refine"
output = "{output}"
""" + TEN_STEPS + """[sweep]
shear_rate = [1.0, 100.0]
psi_bar = [0.0, 0.8]
B2 = [0.1, 0.2, 0.3]
[refine]
tolerance = {{ shear_rate = 0.02, psi_bar = 0.02 }}
max_cases = {per_refinement}
"""
HPCVES = [sys.executable, "-m", "hpcves.cli"]


def cpu_seconds(pid: int) -> float | None:
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def rank_pids() -> dict[int, int]:
    """{rank: pid} of the running hpcves ranks (OMPI_COMM_WORLD_RANK in their environment)."""
    found = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/environ", "rb") as f:
                env = dict(v.split(b"=", 1) for v in f.read().split(b"\0") if b"=" in v)
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                cmd = f.read()
        except OSError:
            continue
        if b"hpcves.cli" in cmd and b"OMPI_COMM_WORLD_RANK" in env and b"BENCH_SCALE" in env:
            found[int(env[b"OMPI_COMM_WORLD_RANK"])] = int(entry)
    return found


def timed(args, env) -> tuple[float, int, str]:
    """(wall seconds, peak resident kB, stdout) of a command under /usr/bin/time."""
    start = time.perf_counter()
    out = subprocess.run(["/usr/bin/time", "-f", "%M", *args], capture_output=True, text=True, env=env, timeout=7200)
    wall = time.perf_counter() - start
    return wall, int(out.stderr.strip().splitlines()[-1]), out.stdout


def run(cases: int, ranks: int, io: str, refine: bool, directory: Path) -> dict:
    output = directory / "scale.h5"
    study = directory / "scale.toml"
    text = (REFINE.format(output=output, per_refinement=cases // 3) if refine
            else GRID.format(output=output, n=cases))
    study.write_text(text)
    env = {**os.environ, **MPI_ENV, "BENCH_SCALE": "1"}
    command = [shutil.which("mpirun"), "-n", str(ranks), *HPCVES, "campaign", str(study), "--io", io]
    start = time.perf_counter()
    job = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    created, cpu = None, {}
    while job.poll() is None:
        if created is None and output.exists():
            created = time.perf_counter() - start
        for rank, pid in rank_pids().items():
            seconds = cpu_seconds(pid)
            if seconds is not None:
                cpu[rank] = seconds
        time.sleep(0.2)
    wall = time.perf_counter() - start
    log = job.stdout.read()
    if job.returncode != 0:
        raise SystemExit(f"campaign exited {job.returncode}:\n{log[-3000:]}")
    n = json.loads(subprocess.run(HPCVES + ["status", "--json", str(output)], capture_output=True, text=True,
                                  env=env).stdout)["cases"]
    status_json, _, _ = timed(HPCVES + ["status", "--json", str(output)], env)
    status_check, _, _ = timed(HPCVES + ["status", "--check", str(output)], env)
    analyze, memory, _ = timed(HPCVES + ["analyze", str(output), "--out", str(directory / "analysis"),
                                         "--no-case-figures", "--no-write-back"], env)
    stages = [float(s) for s in re.findall(r"; ([0-9.]+) s between stages", log)]
    workers = [cpu[r] for r in cpu if r != 0]
    return {"cases": n, "ranks": ranks, "io": io, "refine": refine, "creation": created or float("nan"),
            "campaign": wall, "rate": n / max(wall - (created or 0.0), 1e-9),
            "cpu_rank0": cpu.get(0, float("nan")),
            "cpu_worker": statistics.median(workers) if workers else float("nan"),
            "status_json": status_json, "status_check": status_check, "analyze": analyze,
            "analyze_gb": memory / 2**20, "file_mb": output.stat().st_size / 1e6,
            "stage_ms_per_case": 1e3 * sum(stages) / max(n, 1) if stages else float("nan"), "log": log[-2000:]}


def row(r: dict) -> str:
    what = f"{r['cases']}{', [refine]' if r['refine'] else ''}, {r['io']}, -n {r['ranks']}"
    return (f"| {what} | {r['creation']:.1f} s | {r['campaign']:.0f} s, {r['rate']:.1f} cases/s | "
            f"{r['cpu_rank0']:.0f} / {r['cpu_worker']:.0f} s | {r['status_json']:.2f} / {r['status_check']:.1f} s | "
            f"{r['analyze']:.0f} s, {r['analyze_gb']:.2f} GB | {r['file_mb']:.0f} MB | "
            + (f"{r['stage_ms_per_case']:.2f} ms |" if r["refine"] else "- |"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, nargs="*", default=[])
    parser.add_argument("--refine", type=int, nargs="*", default=[], help="cases of a [refine] study (3 refinements)")
    parser.add_argument("--ranks", type=int, nargs="+", default=[8])
    parser.add_argument("--io", nargs="+", default=["relay", "mpio"])
    parser.add_argument("--json", help="append each run's numbers to this file as a JSON line")
    args = parser.parse_args()
    print("| cases, I/O, ranks | creation | campaign | CPU rank 0 / worker | status --json / --check | analyze | file "
          "| between stages per added case |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for refine, counts in ((False, args.cases), (True, args.refine)):
        for n in counts:
            for ranks in args.ranks:
                for io in args.io:
                    directory = Path(tempfile.mkdtemp(prefix="hpcves-scale-"))
                    try:
                        result = run(n, ranks, io, refine, directory)
                    finally:
                        shutil.rmtree(directory, ignore_errors=True)
                    print(row(result), flush=True)
                    if args.json:
                        with open(args.json, "a") as f:
                            f.write(json.dumps({k: v for k, v in result.items() if k != "log"}) + "\n")


if __name__ == "__main__":
    main()
