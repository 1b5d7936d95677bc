"""Rank 0's CPU per tiny case under ``--io relay``, by what it does -> BENCHMARKS.md ("Rank 0 under relay").

Runs CASES tiny cases (bench_scale's: N = 16, 10 steps) in one process through the relay's own
code: the worker side (``RemoteCampaign``, ``RemoteCaseStore``) and rank 0's side (``Relay.handle``
and the campaign file) joined by a loopback in place of MPI that pickles every message, as mpi4py
does. Rank 0's share is timed with ``time.thread_time`` around its unpickling and its handling of each
message, by kind; the worker's is the rest. No scheduling, no MPI and no other processes, so the
numbers repeat to a few percent where ``bench_scale``'s /proc samples of 16 oversubscribed ranks do
not. The ratio at R ranks follows as (R - 1) x rank 0 / worker (each worker runs 1/(R-1) of the cases;
MPI start-up and creation left out).

    python bench/bench_relay.py --cases 1000
"""
from __future__ import annotations

import argparse
import collections
import os
import pickle
import statistics
import sys
import tempfile
import time
from pathlib import Path

from bench_scale import TEN_STEPS


class _Done:
    """A request that has completed (the loopback delivers at once)."""

    def Test(self):
        return True

    def Wait(self):
        return None


class Loopback:
    """The MPI calls relay.py makes, between one worker (rank 1) and rank 0 in this process."""

    def __init__(self):
        self.relay = None
        self.replies = collections.deque()
        self.rank0 = collections.Counter()       # seconds of rank 0's thread CPU, by message kind
        self.count = collections.Counter()

    def isend(self, message, dest, tag):
        data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
        if dest != 0:                            # rank 0's reply to the worker
            self.replies.append(data)
            return _Done()
        start = time.thread_time()
        received = pickle.loads(data)
        self.rank0["receive"] += time.thread_time() - start
        kind = received[0] if received[0] != "read" else f"read {received[2]}"
        start = time.thread_time()
        self.relay.handle(self, 1, received)
        self.rank0[kind] += time.thread_time() - start
        self.count[kind] += 1
        return _Done()

    def Iprobe(self, source, tag):
        return bool(self.replies)

    def recv(self, source, tag):
        return pickle.loads(self.replies.popleft())


def run(cases: int, directory: Path) -> dict:
    from hpcves.campaign.file import CampaignFile
    from hpcves.campaign.queue import Task
    from hpcves.campaign.relay import Relay, RemoteCampaign
    from hpcves.campaign.scheduler import run_one
    from hpcves.campaign.structure import file_bytes
    from hpcves.campaign.study import study_from_toml
    from hpcves.files.atomic import new_partial
    from hpcves.run.store import FINISHED, open_file, safe_flush

    output = directory / "relay.h5"
    study = study_from_toml(f'[campaign]\nname = "relay"\noutput = "{output}"\n{TEN_STEPS}'
                            f"[sweep]\nshear_rate = {{ linspace = [1, 100, {cases}] }}\n")
    h5 = open_file(new_partial(output, file_bytes(study), "the campaign file"), "r+")
    campaign = CampaignFile.create(h5, study)
    h5.flush()
    comm = Loopback()
    comm.relay = Relay(campaign, safe_flush(h5), reply_tag=2)
    remote = RemoteCampaign(comm, 1, 2, wait=lambda ready: ready())
    per_case = []
    for case in study.cases:
        start = time.thread_time()
        before = sum(comm.rank0.values())
        begin = time.thread_time()                 # rank 0 sends the case's stored text with its task
        task = Task(case.case_id, resume=False, config=comm.relay.config(case.case_id))
        task = pickle.loads(pickle.dumps(task, protocol=pickle.HIGHEST_PROTOCOL))
        comm.rank0["task"] += time.thread_time() - begin
        result = run_one(remote, task, remote.flush, 1, lambda: False,
                         lambda fraction: None, study.analysis)
        if result.status != FINISHED:
            raise SystemExit(f"case {case.case_id}: {result.message}")
        total = time.thread_time() - start
        rank0 = sum(comm.rank0.values()) - before
        per_case.append((rank0, total - rank0))
    h5.close()
    n = len(per_case)
    return {"cases": n,
            "rank0_ms": 1e3 * statistics.median(r for r, _ in per_case),
            "worker_ms": 1e3 * statistics.median(w for _, w in per_case),
            "by_kind_ms": {k: 1e3 * v / n for k, v in sorted(comm.rank0.items(), key=lambda kv: -kv[1])},
            "messages_per_case": {k: v / n for k, v in comm.count.items()}}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=3, help="runs; the table gives each")
    args = parser.parse_args(argv)
    rows = []
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory(prefix="hpcves-relay-") as directory:
            rows.append(run(args.cases, Path(directory)))
    print(f"{os.uname().nodename}, {time.strftime('%Y-%m-%d %H:%M')}, {args.cases} tiny cases a run\n")
    print("| run | rank 0 ms / case | worker ms / case | -n 8 | -n 16 | rank 0 by kind (ms / case) |")
    print("| ---: | ---: | ---: | ---: | ---: | --- |")
    for k, row in enumerate(rows, 1):
        r0, w = row["rank0_ms"], row["worker_ms"]
        kinds = ", ".join(f"{kind} {ms:.3f}" for kind, ms in row["by_kind_ms"].items())
        print(f"| {k} | {r0:.3f} | {w:.2f} | {7 * r0 / w:.2f}x | {15 * r0 / w:.2f}x | {kinds} |")
    print("\nmessages a case:", ", ".join(f"{k} {v:g}" for k, v in rows[-1]["messages_per_case"].items()))
    return rows


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    main()
