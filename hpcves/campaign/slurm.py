"""A SLURM batch script for a study, sized from its plan (``hpcves campaign --plan --slurm``).

The script is a template filled in (``{{ name }}`` placeholders, the syntax of Jinja's variables):
the default, templates/slurm.sh, first submits its successor (``--dependency=afterany``: it starts
once this job has ended, however it ended -- a lost node, an out-of-memory kill), runs ``hpcves
campaign --resume`` under srun, asks ``hpcves status --json`` what is left, and cancels the successor
once nothing is (status exit 0 or 1) -- a study larger than one job's wall time goes on in the next
job, from the checkpoints -- unless MAX_IDLE_JOBS jobs in a row advanced nothing or the chain has run
its MAX_JOBS. A site
brings its own template (``--slurm-template FILE``) with the same placeholders
(:data:`PLACEHOLDERS`; docs/cluster.md). Every path in it is absolute, so it runs from any directory.
"""
from __future__ import annotations

import math
import re
import shlex
from dataclasses import dataclass
from pathlib import Path

from hpcves.config import did_you_mean, not_a_regular_file
from hpcves.model.params import ConfigError

#: seconds before the wall time at which SLURM sends SIGTERM: the campaign's stop_timeout
#: (every rank checkpoints) plus this margin for the status call and the resubmission
SIGNAL_MARGIN = 60
#: jobs in a row that advance nothing (no case added, no simulated time) before the chain stops
MAX_IDLE_JOBS = 2
#: the memory asked per rank over what the model (run/timing.py rank_bytes) says a rank holds
MEMORY_MARGIN = 1.25
#: the default template
TEMPLATE = Path(__file__).with_name("templates") / "slurm.sh"
_PLACEHOLDER = re.compile(r"\{\{\s*(\w+)\s*\}\}")

#: what a template may use, and what each holds (docs/cluster.md shows this table)
PLACEHOLDERS = {
    "job_name": "the job's name: hpcves-<study name> (characters other than letters, digits, . _ - + as _)",
    "summary": "the plan in a line: cases, core-hours, wall time on the ranks",
    "script": "the batch script's own path (shell-quoted)",
    "ranks": "MPI ranks to ask for (--ntasks)",
    "time": "the wall time a job asks for, D-HH:MM:SS (--time)",
    "signal_seconds": "seconds before the wall time that SIGTERM is to come (--signal=TERM@...)",
    "mem_per_cpu": "memory a rank needs, in MiB with SLURM's unit: e.g. 640M (--mem-per-cpu)",
    "memory_note": "how mem_per_cpu was sized, in a line",
    "log": "the log file name: hpcves-<study name, as in job_name>-%j.log",
    "workdir": "the directory --plan ran in (shell-quoted)",
    "study_file": "the study file (shell-quoted)",
    "output": "the campaign file (shell-quoted)",
    "hpcves": "the hpcves command (shell-quoted)",
    "python": "the Python that runs hpcves (shell-quoted)",
    "max_jobs": "the most jobs the chain may run, resubmissions included",
    "max_idle_jobs": f"jobs in a row that advance nothing before the chain stops ({MAX_IDLE_JOBS})",
}


@dataclass(frozen=True)
class JobSize:
    ranks: int
    wall_seconds: float          # what the job asks for (#SBATCH --time)
    rank_bytes: int              # what a rank holds at the study's largest N (run/timing.py rank_bytes)
    max_jobs: int                # the cap on the chain's jobs


def job_time(seconds: float) -> str:
    """SLURM's --time: D-HH:MM:SS."""
    seconds = int(math.ceil(seconds))
    days, rest = divmod(seconds, 86400)
    hours, rest = divmod(rest, 3600)
    minutes, seconds = divmod(rest, 60)
    return (f"{days}-" if days else "") + f"{hours:02d}:{minutes:02d}:{seconds:02d}"


def max_jobs(wall_seconds: float, job_seconds: float) -> int:
    """The default cap on a chain's jobs: twice the jobs the plan's wall time needs, plus one (cases
    slower here than where they were timed, a node lost); the idle-job rule stops a chain that
    makes no progress long before."""
    return 2 * max(1, math.ceil(wall_seconds / job_seconds)) + 1


def mem_per_cpu(rank_bytes: int) -> int:
    """MiB to ask per rank: the model's bytes times MEMORY_MARGIN, rounded up to 64 MiB."""
    return 64 * math.ceil(MEMORY_MARGIN * rank_bytes / 2**20 / 64)


#: the largest template read (a batch script is a few kB; a larger file is something else)
TEMPLATE_BYTES = 1 << 20
_BRACES = re.compile(r"\{\{(.*?)\}\}", re.DOTALL)


def read_template(path: Path | None) -> str:
    """The text of the template at ``path`` (None: the default), its placeholders checked. A device,
    a pipe, a file over TEMPLATE_BYTES or one that is not UTF-8 text is refused before it is read
    whole (/dev/zero or a FIFO would hang the reading)."""
    where = str(path) if path else "the default template"
    source = Path(path or TEMPLATE)
    try:
        kind = not_a_regular_file(source)
        if kind:
            raise ConfigError(f"--slurm-template {path}: {kind}, not a template file")
        if source.stat().st_size > TEMPLATE_BYTES:
            raise ConfigError(f"--slurm-template {path}: {source.stat().st_size} bytes, more than a batch script's "
                              f"{TEMPLATE_BYTES} at most: not a template")
        text = source.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"--slurm-template {path}: not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at offset "
                          f"{exc.start}): not a template") from None
    except OSError as exc:
        raise ConfigError(f"--slurm-template {path}: cannot read it ({exc.strerror or exc})") from None
    malformed = [m.group(0) for m in _BRACES.finditer(text) if not _PLACEHOLDER.fullmatch(m.group(0))]
    if malformed:
        raise ConfigError(f"{where}: {malformed[0]!r} is not a placeholder (a name of letters, digits and '_' "
                          f"in double braces, e.g. {{{{ job_name }}}}); a template may use {', '.join(PLACEHOLDERS)}"
                          " (docs/cluster.md)")
    if not re.search(r"^#SBATCH[ \t].*--signal=", text, re.M):
        raise ConfigError(f"{where}: no '#SBATCH --signal=TERM@{{{{ signal_seconds }}}}' line: without it SLURM kills "
                          "the ranks at the wall time instead of asking them to checkpoint first, and each job loses "
                          "what its cases computed since their last checkpoint; add the line (docs/cluster.md)")
    unknown = sorted({m.group(1) for m in _PLACEHOLDER.finditer(text)} - set(PLACEHOLDERS))
    if unknown:
        def named(name: str) -> str:
            suggested = did_you_mean(name, PLACEHOLDERS).removeprefix(name)     # " (did you mean x?)" or ""
            return "{{ " + name + " }}" + re.sub(r"mean (\w+)\?", r"mean {{ \1 }}?", suggested)

        raise ConfigError(f"{where}: unknown placeholder{'s' * (len(unknown) > 1)} "
                          + ", ".join(named(u) for u in unknown)
                          + f"; a template may use {', '.join(PLACEHOLDERS)} (docs/cluster.md)")
    return text


def refuse_unsafe_paths(**paths) -> None:
    """Refuse a path for the batch script that holds a line break or another control character: in a
    comment line a line break ends the comment and the rest runs as shell code (quoting does not help
    there). ``paths``: {placeholder: path}."""
    for name, path in paths.items():
        shown = str(Path(path).absolute())
        if not shown.isprintable():
            raise ConfigError(f"{name.replace('_', ' ')} {shown!r}: its path holds a line break or another control "
                              "character, which a batch script cannot hold safely; rename it")


def _job_label(name: str) -> str:
    """The study's name as it may stand in an ``#SBATCH`` line (which sbatch splits at spaces) and a
    file name: every character but letters, digits, '.', '_', '-' and '+' as '_'."""
    return re.sub(r"[^A-Za-z0-9._+-]", "_", name)


def fill(text: str, values: dict[str, str]) -> str:
    """``text`` with every ``{{ name }}`` replaced by ``values[name]`` (checked by :func:`read_template`)."""
    return _PLACEHOLDER.sub(lambda m: values[m.group(1)], text)


def slurm_script(*, script: Path, study_name: str, study_file: Path, output: Path, size: JobSize, hpcves: Path,
                 python: Path, workdir: Path, stop_timeout: float, summary: str, largest_N: int,
                 template: str | None = None) -> str:
    """The batch script's text: ``template`` (:func:`read_template`'s text; None: the default) filled in
    (paths made absolute)."""
    def q(p) -> str:
        return shlex.quote(str(Path(p).absolute()))       # not resolve(): a venv's python is a link

    refuse_unsafe_paths(script=script, study_file=study_file, output=output, hpcves=hpcves, python=python,
                        workdir=workdir)
    label = _job_label(study_name)

    text = read_template(None) if template is None else template
    memory = mem_per_cpu(size.rank_bytes)
    values = {
        "job_name": f"hpcves-{label}",
        "summary": summary,
        "script": q(script),
        "ranks": str(size.ranks),
        "time": job_time(size.wall_seconds),
        "signal_seconds": str(int(math.ceil(stop_timeout)) + SIGNAL_MARGIN),
        "mem_per_cpu": f"{memory}M",
        "memory_note": (f"{memory} MiB a rank: {MEMORY_MARGIN:g} x the {size.rank_bytes / 2**20:.0f} MiB that a "
                        f"rank holds at N = {largest_N} compiling its engine (run/timing.py rank_bytes, "
                        "measured: BENCHMARKS.md, \"Memory of a rank\")"),
        "log": f"hpcves-{label}-%j.log",
        "workdir": q(workdir),
        "study_file": q(study_file),
        "output": q(output),
        "hpcves": q(hpcves),
        "python": q(python),
        "max_jobs": str(size.max_jobs),
        "max_idle_jobs": str(MAX_IDLE_JOBS),
    }
    return fill(text, values)
