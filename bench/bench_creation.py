"""Laying out a campaign file -> the "Creating a campaign file" section of BENCHMARKS.md.

Times ``structure.create_file`` (``driver._create`` before; the file laid out under ``.partial`` and
renamed) for tiny cases (N = 16, t_end = 0.01) at several numbers of cases, under ``mpirun -n`` ranks
with each I/O mode; medians of ``--repeat`` runs. ``--code DIR`` times the hpcves in DIR instead (a
worktree of an older commit), so that two versions are measured in one run on the same machine.

    python bench/bench_creation.py --cases 500 2000 --ranks 1 8 --out BENCHMARKS.md
"""
from __future__ import annotations

import argparse
import inspect
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

STUDY = """
[campaign]
name = "creation"
output = "{output}"
t_end = 0.01
[numerics]
N = 16
dt = 1e-3
[run]
max_spectral_tail = 1.0
sample_interval = 0.001
snapshot_interval = 0.005
checkpoint_interval = 0.005
[sweep]
shear_rate = {{ linspace = [1, 100, {n}] }}
"""
MPI_ENV = {"OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
           "OMPI_MCA_rmaps_base_oversubscribe": "1", "OMPI_MCA_pml": "ob1", "OMPI_MCA_btl": "self,vader",
           "OMPI_MCA_btl_vader_single_copy_mechanism": "none"}


def job(n: int, io: str, directory: str) -> None:
    """Under mpirun: lay the file out once, print the seconds on rank 0."""
    from mpi4py import MPI

    from hpcves.campaign import driver
    from hpcves.campaign.access import choose_io, file_access
    from hpcves.campaign.study import study_from_toml

    comm = MPI.COMM_WORLD if MPI.COMM_WORLD.Get_size() > 1 else None
    output = Path(directory) / "creation.h5"
    study = study_from_toml(STUDY.format(output=output, n=n))
    args = (study, output, comm)
    try:
        from hpcves.campaign.structure import create_file
    except ImportError:                                                # the hpcves before the driver was split
        create_file = driver._create
    if "access" in inspect.signature(create_file).parameters:      # the hpcves before rank 0 laid out alone
        access = (file_access(choose_io(io, comm.Get_size()), comm, 11, 12) if comm
                  else file_access("auto", None, 11, 12))
        args += (access,)
    if comm:
        comm.Barrier()
    start = time.perf_counter()
    create_file(*args)
    if comm:
        comm.Barrier()
    seconds = time.perf_counter() - start
    if comm is None or comm.Get_rank() == 0:
        print(json.dumps({"seconds": seconds, "bytes": output.stat().st_size}))


def measure(n: int, ranks: int, io: str, code: str | None) -> float:
    directory = tempfile.mkdtemp(prefix="hpcves-creation-")
    env = {**os.environ, **MPI_ENV}
    if code:
        env["PYTHONPATH"] = code
    command = [sys.executable, __file__, "--job", str(n), io, directory]
    if ranks > 1:
        command = [shutil.which("mpirun"), "-n", str(ranks)] + command
    try:
        out = subprocess.run(command, capture_output=True, text=True, env=env, timeout=3600, check=True).stdout
    finally:
        shutil.rmtree(directory, ignore_errors=True)
    return json.loads(out.strip().splitlines()[-1])["seconds"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--job", nargs=3, help=argparse.SUPPRESS)
    parser.add_argument("--cases", type=int, nargs="+", default=[500])
    parser.add_argument("--ranks", type=int, nargs="+", default=[1, 8])
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--code", nargs="*", default=[], help="LABEL=DIR: other hpcves versions to time as well")
    args = parser.parse_args()
    if args.job:
        job(int(args.job[0]), args.job[1], args.job[2])
        return
    versions = [("this", None)] + [tuple(c.split("=", 1)) for c in args.code]
    print("| version | cases | ranks | I/O | seconds | ms per case |")
    print("| --- | ---: | ---: | --- | ---: | ---: |")
    for n in args.cases:
        for ranks in args.ranks:
            for io in (["serial"] if ranks == 1 else ["mpio", "relay"]):
                for label, code in versions:
                    seconds = statistics.median(measure(n, ranks, io, code) for _ in range(args.repeat))
                    print(f"| {label} | {n} | {ranks} | {io} | {seconds:.2f} | {1e3 * seconds / n:.1f} |", flush=True)


if __name__ == "__main__":
    main()
