"""Fault injection: kill real MPI campaigns at random moments, resume them, compare bit for bit.

    python tests/faults.py --kills 40 --out FAULTS.md            # what `make faults` runs

Each trial runs the study below under ``mpirun -n 2`` or ``-n 3``, with ``--io mpio`` or
``--io relay``, with a fixed or an adaptive time step (``dt`` or ``rtol``: the step controller's
state must resume bitwise too), and SIGKILLs the whole job at a random moment. The moment is drawn from a timeline
measured first for that set-up, so that a quarter of the kills fall while the file is created,
half while the cases run, and a quarter at the very end (the last cases finishing, the summary,
the close). A quarter of the trials kill only mpirun's process group, which leaves the ranks
running for a moment, and start the resume at once: the lock must refuse it until the ranks are
gone. A third of the resumes are killed again. Every trial ends with a resume to completion and
a comparison of every dataset and status with an uninterrupted run (jobs.differences).

Where each kill landed is read off what it left behind: no file yet, only ``.partial`` (during
creation), cases running, a checkpoint slot marked invalid with data in it (inside a checkpoint
write), every case finished (at the very end).

tests/test_faults.py runs a small deterministic subset (exact kill points via HPCVES_FAULT, and
two random kills) as part of ``make test``.
"""
from __future__ import annotations

import argparse
import datetime
import os
import platform
import random
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from jobs import alive, case_views, command, differences, job_pids, kill_job, mpi_env, start_job, wait_until  # noqa: E402

STUDY = """[campaign]
name = "faults"
output = "{output}"
t_end = 0.06

[numerics]
N = 32
{stepping}

[run]
max_spectral_tail = 1.0          # N = 32 on purpose (fast): the resolution watch would stop it
sample_interval = 0.005
snapshot_interval = 0.02
checkpoint_interval = 0.01
checkpoint_wall = 0

[sweep]
shear_rate = {{ linspace = [10, 160, {points}] }}
psi_bar = [0.3, 0.4, 0.5]
"""
#: (ranks, io, time stepping): each io with each stepping
SETUPS = [(2, "mpio", "fixed"), (3, "relay", "adaptive"), (3, "mpio", "adaptive"), (2, "relay", "fixed")]
#: the [numerics] line of each time stepping
STEPPING = {"fixed": "dt = 1e-3", "adaptive": "rtol = 1e-2"}
AFTER = "after the job ended"          # a kill that came too late: the job had ended by itself


POINTS = 20                            # shear rates: 3 x 20 = 60 cases, whose creation takes a while


def write_study(directory: Path, points: int = POINTS, stepping: str = "fixed") -> tuple[Path, Path]:
    directory.mkdir(parents=True, exist_ok=True)
    output = directory / "faults.h5"
    path = directory / "faults.toml"
    path.write_text(STUDY.format(output=output, points=points, stepping=STEPPING[stepping]))
    return path, output


def reference(directory: Path, points: int = POINTS, stepping: str = "fixed") -> Path:
    """The study run uninterrupted, serially in this process."""
    from hpcves.campaign.driver import run_campaign
    from hpcves.campaign.study import study_from_toml

    path, output = write_study(directory, points, stepping)
    if not output.exists():
        assert run_campaign(study_from_toml(path.read_text()), output).exit_status == 0
    return output


def campaign_args(path, io, resume=False):
    return ("campaign", path, "--quiet", "--io", io) + (("--resume",) if resume else ())


# ---------------------------------------------------------------------- where a job is in its life
@dataclass
class Timeline:
    """Seconds from the start of an uninterrupted job to each of its moments."""

    partial: float          # <file>.partial appears: creation begins
    file: float             # the file appears: creation done
    done: float             # every case finished
    exit: float             # the job has ended


def measure(directory: Path, n: int, io: str, points: int = POINTS, stepping: str = "fixed") -> Timeline:
    path, output = write_study(directory, points, stepping)
    partial = output.with_name(output.name + ".partial")
    seen = {}
    start = time.monotonic()
    job = start_job(n, *campaign_args(path, io))
    while job.poll() is None:
        now = time.monotonic() - start
        if "partial" not in seen and partial.exists():
            seen["partial"] = now
        if "file" not in seen and output.exists():
            seen["file"] = now
        if "file" in seen and "done" not in seen and all_finished(output):
            seen["done"] = now
        # fine steps until the file exists (creation can be short), then coarser: reading the file
        # every few ms slows the job on a loaded machine, and the moments measured would be late
        time.sleep(0.003 if "file" not in seen else 0.02)
    end = time.monotonic() - start
    assert job.returncode == 0, job.communicate()
    file = seen.get("file", end)
    return Timeline(seen.get("partial", file), file, seen.get("done", end), end)


def all_finished(output: Path) -> bool:
    with h5py.File(output, "r", locking=False) as f:
        return all(int(g["status"][()]) == 2 for _, g in case_views(f))


def landed(output: Path) -> str:
    """Where a kill landed, from what it left."""
    partial = output.with_name(output.name + ".partial")
    if not output.exists():
        return "during creation" if partial.exists() else "before creation"
    with h5py.File(output, "r", locking=False) as f:
        views = [g for _, g in case_views(f)]
        statuses = [int(g["status"][()]) for g in views]
        torn = sum(1 for g in views for s in ("slot0", "slot1")
                   if g[f"checkpoint/{s}/meta"][0] == 0 and np.isfinite(g[f"checkpoint/{s}/scalars"][0]))
    if all(s == 2 for s in statuses):
        return "at the very end"
    where = "while cases ran"
    return where + (f" (inside {torn} checkpoint write{'s' * (torn > 1)})" if torn else "")


# ---------------------------------------------------------------------- one trial
@dataclass
class Trial:
    n: int
    io: str
    planned: str
    mode: str                               # "job": every process; "group": mpirun's process group only
    stepping: str = "fixed"                 # "fixed" (dt) or "adaptive" (rtol)
    kills: list = field(default_factory=list)   # where each kill landed
    refused: int = 0                        # resumes the lock refused (ranks still alive)
    differences: list = field(default_factory=list)
    seconds: float = 0.0

    @property
    def identical(self) -> bool:
        return not self.differences

    @property
    def landed(self) -> int:
        """Kills that hit a live job."""
        return sum(1 for k in self.kills if k != AFTER)


def kill_group(job) -> set:
    """SIGKILL mpirun's process group only (its ranks have groups of their own); the ranks' pids."""
    ranks = job_pids(job.pid) - {job.pid}
    try:
        os.killpg(job.pid, signal.SIGKILL)
    except ProcessLookupError:              # it had just ended by itself
        pass
    job.communicate()
    return ranks


def run_to_completion(path, output, n, io, trial: Trial, lingering=frozenset()):
    """Resume until the campaign is finished; a refusal by the lock waits for the old ranks."""
    while True:
        result = subprocess.run(command(n, *campaign_args(path, io, resume=True)), capture_output=True,
                                text=True, env=mpi_env(), timeout=600)
        if result.returncode == 0:
            return
        if result.returncode == 2 and ("still running" in result.stderr or "is writing this file" in result.stderr):
            trial.refused += 1
            wait_until(lambda: not any(alive(p) for p in lingering), "the old ranks are gone")
            continue
        raise AssertionError(f"resume failed ({result.returncode}): {result.stderr}")


def trial(directory: Path, n: int, io: str, timeline: Timeline, rng: random.Random, ref: Path,
          planned: str | None = None, mode: str | None = None, again: bool | None = None,
          points: int = POINTS, stepping: str = "fixed") -> Trial:
    """Kill the job once at a moment drawn from ``timeline`` (``planned``: creation, running or end),
    perhaps kill the resume too, resume to the end, compare with ``ref``."""
    import shutil

    shutil.rmtree(directory, ignore_errors=True)
    path, output = write_study(directory, points, stepping)
    planned = planned or rng.choices(["creation", "running", "end"], weights=[1, 2, 1])[0]
    mode = mode or rng.choices(["job", "group"], weights=[3, 1])[0]
    window = {"creation": (timeline.partial, timeline.file), "running": (timeline.file, timeline.done),
              "end": (timeline.done - 0.3 * (timeline.done - timeline.file), timeline.exit)}[planned]
    record = Trial(n, io, planned, mode, stepping)
    started = time.monotonic()
    job = start_job(n, *campaign_args(path, io), own_group=(mode == "group"))
    _sleep_until(started + rng.uniform(*window), job)
    lingering = set()
    if mode == "group":
        lingering = kill_group(job)
    else:
        kill_job(job)
    record.kills.append(landed(output) if job.returncode != 0 else AFTER)
    if mode == "group":                     # resume at once, while the ranks may still run
        run_to_completion(path, output, n, io, record, lingering)
    else:
        if again if again is not None else rng.random() < 1 / 3:
            resumed = time.monotonic()
            job = start_job(n, *campaign_args(path, io, resume=True))
            _sleep_until(resumed + rng.uniform(0.3, timeline.exit), job)
            kill_job(job)
            record.kills.append(landed(output) if job.returncode != 0 else AFTER)
        run_to_completion(path, output, n, io, record)
    record.differences = differences(output, ref)
    record.seconds = time.monotonic() - started
    return record


def _sleep_until(moment: float, job) -> None:
    while time.monotonic() < moment and job.poll() is None:
        time.sleep(min(0.002, max(moment - time.monotonic(), 0.0)))


# ---------------------------------------------------------------------- the whole experiment
def experiment(work: Path, kills: int, seed: int, progress=print) -> tuple[list[Trial], dict]:
    import shutil

    # from nothing: a second run found the timelines' files of the first (refused without --overwrite)
    # and would have compared with references an older hpcves wrote
    shutil.rmtree(work, ignore_errors=True)
    rng = random.Random(seed)
    refs = {stepping: reference(work / f"reference-{stepping}", stepping=stepping) for stepping in STEPPING}
    timelines = {}
    for setup in SETUPS:
        n, io, stepping = setup
        timelines[setup] = measure(work / f"timeline-{n}-{io}-{stepping}", n, io, stepping=stepping)
        progress(f"timeline -n {n} --io {io}, {stepping} step: {timelines[setup]}")
    trials, landed = [], 0
    while landed < kills:                   # a kill that came after the job had ended does not count
        n, io, stepping = setup = SETUPS[len(trials) % len(SETUPS)]
        t = trial(work / "trial", n, io, timelines[setup], rng, refs[stepping], stepping=stepping)
        trials.append(t)
        landed += t.landed
        progress(f"{landed:3d}/{kills}  -n {n} {io:5} {stepping:8}  {t.planned:8} {t.mode:5}  "
                 f"killed {' / '.join(t.kills)}"
                 f"{f'; {t.refused} resume(s) refused' if t.refused else ''}  ->  "
                 f"{'identical' if t.identical else 'DIFFERENT: ' + repr(t.differences[:3])}")
    return trials, timelines


def report(trials: list[Trial], timelines: dict, seed: int, wall: float) -> str:
    identical = sum(t.identical for t in trials)
    landings = {}
    for t in trials:
        for k in t.kills:
            if k != AFTER:
                key = k.split(" (")[0]
                landings[key] = landings.get(key, 0) + 1
    torn = sum(1 for t in trials for k in t.kills if "checkpoint write" in k)
    late = sum(1 for t in trials for k in t.kills if k == AFTER)
    refused = sum(t.refused for t in trials)
    lines = [
        "# Fault injection (`make faults`)", "",
        f"{datetime.date.today()}, {platform.node()} ({os.cpu_count()} cores), seed {seed}, {wall / 60:.1f} min. "
        "Written by `tests/faults.py` (its docstring says how the kills are chosen).", "",
        f"**{identical} of {len(trials)} trials resumed to results bitwise identical to an uninterrupted run**, "
        f"after {sum(t.landed for t in trials)} SIGKILLs of live jobs "
        f"({sum(1 for t in trials if t.landed)} trials with a kill; {late} {'kill' if late == 1 else 'kills'} came "
        f"after the job had ended and {'does' if late == 1 else 'do'} not count; {refused} "
        f"{'resume was' if refused == 1 else 'resumes were'} "
        "refused by the lock while the ranks of a killed mpirun were still alive, and ran once they were gone).", "",
        "Where the kills landed: " + ", ".join(f"{n} {k}" for k, n in sorted(landings.items(), key=lambda x: -x[1]))
        + f"; {torn} of them inside a checkpoint write.", "",
        "Timelines of uninterrupted jobs (seconds from mpirun's start):", "",
        "| set-up | creation starts | file complete | all cases done | job ends |",
        "| --- | ---: | ---: | ---: | ---: |"]
    lines += [f"| -n {n} --io {io}, {stepping} step | {tl.partial:.2f} | {tl.file:.2f} | {tl.done:.2f} | "
              f"{tl.exit:.2f} |" for (n, io, stepping), tl in timelines.items()]
    lines += ["", "| # | set-up | aimed at | kill | landed | resumes refused | result |",
              "| ---: | --- | --- | --- | --- | ---: | --- |"]
    lines += [f"| {i + 1} | -n {t.n} --io {t.io}, {t.stepping} | {t.planned} | {t.mode} | {' / '.join(t.kills)} | "
              f"{t.refused} | "
              f"{'identical' if t.identical else 'DIFFERENT'} |" for i, t in enumerate(trials)]
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kills", type=int, default=40, help="SIGKILLs of live jobs to make (one or two a trial)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--work", type=Path, default=Path("out/faults"))
    parser.add_argument("--out", type=Path, help="write the report (Markdown) here")
    args = parser.parse_args()
    started = time.monotonic()
    trials, timelines = experiment(args.work, args.kills, args.seed)
    text = report(trials, timelines, args.seed, time.monotonic() - started)
    print(text)
    if args.out:
        args.out.write_text(text)
    return 0 if all(t.identical for t in trials) else 1


if __name__ == "__main__":
    sys.exit(main())
