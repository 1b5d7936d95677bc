"""hpcves campaign --plan: cases, core-hours, ranks and wall time; the SLURM script sized from it."""
import dataclasses
import os
import re
import stat
import subprocess

import pytest

from hpcves.campaign.driver import run_campaign
from hpcves.campaign.plan import Plan, Stage, makespan, plan
from hpcves.campaign.slurm import mem_per_cpu
from hpcves.campaign.study import load_study, study_from_toml
from hpcves.model.params import Case, Numerics, Physics, RunControl
from hpcves.run.timing import StepCost, rank_bytes
from jobs import hpcves, mpi_env, start_job

TINY = """
[campaign]
name = "{name}"
output = "{output}"
t_end = 0.2
[numerics]
N = 32
dt = 1e-3
[run]
max_spectral_tail = 1.0
sample_interval = 0.01
snapshot_interval = 0.1
checkpoint_interval = 0.1
"""


def per_step(case):                      # a step of a fixed cost: the plan's arithmetic alone
    return 1e-3 * (case.numerics.N / 32) ** 2


def test_the_settled_step_shrinks_as_the_cube_root_of_rtol(tmp_path):
    text = TINY.replace("dt = 1e-3", "rtol = RTOL").replace("sample_interval = 0.01", "sample_interval = 1.0")
    steps = [study_from_toml(text.format(name="e", output=tmp_path / "e.h5").replace("RTOL", str(rtol))
                             + "[sweep]\nshear_rate = [40]\n").cases[0].case.estimated_steps
             for rtol in (1e-2, 1e-3)]
    assert steps[0] == pytest.approx(0.2 / (0.05 / 40))                 # t_end over the settled step at S = 40
    assert steps[1] / steps[0] == pytest.approx(10 ** (1 / 3))


def test_makespan_replays_the_scheduler_longest_first_to_the_rank_free_first():
    assert makespan([3, 3, 2, 2, 2], 2) == 7          # LPT: {3, 2, 2} and {3, 2}; the optimum is 6
    assert makespan([5, 1, 1, 1], 2) == 5
    assert makespan([2, 2], 5) == 2 and makespan([], 3) == 0.0
    assert makespan([1.0] * 10, 1) == 10.0


def test_the_suggested_ranks_are_the_fewest_near_the_fastest():
    # one long case and ten short ones: two ranks do as well as eleven
    assert Plan("x", "grid", (Stage("grid", (10.0,) + (1.0,) * 10),), {}, 1).suggested_ranks() == 2
    equal = Plan("x", "grid", (Stage("grid", (1.0,) * 12),), {}, 1)
    # on more than four ranks rank 0 only schedules: 12 cases at once take 13 ranks
    assert equal.suggested_ranks() == 13 and equal.wall(13) == 1.0 and equal.wall(12) == 2.0
    assert equal.wall(4) == equal.wall(5) == 3.0 and equal.wall(6) == 3.0 and equal.wall(7) == 2.0
    # stages run one after the other: their walls add up
    staged = Plan("x", "search", (Stage("start", (2.0,) * 4), Stage("splits", (1.0,) * 2, rounds=3)), {}, 2)
    assert staged.cases == 10 and staged.core_seconds == 14.0
    assert staged.wall(2) == 4.0 + 3 * 1.0 and staged.wall(4) == 2.0 + 3 * 1.0
    assert staged.suggested_ranks() == 4 and staged.widest == 4


def test_laying_out_on_rank_0_keeps_many_short_cases_from_one_rank_each(tmp_path):
    """2000 cases of 0.1 core-seconds: without the layout the plan asked for a rank a case, whose job
    the creation alone outlasts (2001 ranks: on more than four, rank 0 only schedules); with 10 ms a case on rank
    0 first, ~100 ranks, ~20 cases each."""
    study = study_from_toml(TINY.format(name="g", output=tmp_path / "g.h5")
                            + "[sweep]\nshear_rate = { linspace = [10, 20, 40] }\n"
                            + "psi_bar = { linspace = [0.1, 0.5, 50] }\n")
    per_case = lambda case: 0.1 / case.estimated_steps                              # noqa: E731
    bare = plan(study, per_case)
    counted = plan(study, per_case, lambda case: 0.01, lambda case: 0.002)
    assert counted.creation == pytest.approx(0.01 * 2000) and counted.analysis == pytest.approx(0.002 * 2000)
    assert counted.core_seconds == bare.core_seconds                  # a grid's runs classify nothing
    assert counted.wall(4) == pytest.approx(bare.wall(4) + 20.0)
    assert bare.suggested_ranks() == 2001 and counted.suggested_ranks() <= 100      # wall 20 s + 200 s / ranks
    assert 2000 / counted.suggested_ranks() >= 20
    refine = study_from_toml(TINY.format(name="r", output=tmp_path / "r.h5")
                             + "[sweep]\nshear_rate = [10, 40]\npsi_bar = [0.3, 0.5]\n[refine]\nmax_cases = 20\n")
    staged = plan(refine, per_case, lambda case: 0.01, lambda case: 0.002)
    # a staged study's case is classified where it ran, as it ends: in its time, not rank 0's
    assert staged.core_seconds == pytest.approx(plan(refine, per_case).core_seconds + 0.002 * staged.cases)
    assert staged.wall(1) == pytest.approx(plan(refine, per_case).wall(1) + 0.012 * staged.cases)


def test_a_grid_plan_prices_every_case(tmp_path):
    study = study_from_toml(TINY.format(name="g", output=tmp_path / "g.h5")
                            + "[sweep]\nshear_rate = [10, 20, 40]\npsi_bar = [0.3, 0.5]\n")
    estimate = plan(study, per_step)
    assert estimate.mode == "grid" and estimate.cases == 6 and len(estimate.stages) == 1
    assert estimate.core_seconds == pytest.approx(sum(c.case.estimated_steps for c in study.cases) * 1e-3)
    assert estimate.step_seconds == {32: (1e-3, 1e-3)} and not estimate.ceiling


def test_a_search_plan_bounds_the_cases_by_convergence_and_budget(tmp_path):
    text = TINY.format(name="s", output=tmp_path / "s.h5") + """
[search]
low = 10.0
high = 160.0
rel_tol = 0.05
max_cases = 12
points = {points}
[sweep]
psi_bar = [0.3, 0.5, 0.7]
"""
    for points in (1, 2):
        study = study_from_toml(text.format(points=points))
        settings = study.search
        estimate = plan(study, per_step)
        most = min(settings.cases_needed(), settings.max_cases)
        assert estimate.first.cases == 3 * (points + 1)
        assert estimate.cases == 3 * (points + 1 + estimate.stages[1].rounds * points) >= 3 * most
        assert estimate.cases - 3 * most < 3 * points          # the last round may be partial
        assert 1 + estimate.stages[1].rounds == settings.stages_needed()
        assert estimate.widest == 3 * (points + 1)


def test_a_refine_plan_spends_the_budget_over_the_halvings(tmp_path):
    study = study_from_toml(TINY.format(name="r", output=tmp_path / "r.h5") + """
[refine]
tolerance = { shear_rate = 0.1, psi_bar = 0.05 }
max_cases = 40
[sweep]
shear_rate = [10, 40, 160]
psi_bar = [0.3, 0.5, 0.7]
B2 = [0.1, 0.8]
""")
    estimate = plan(study, per_step)
    settings = study.refine_settings
    assert estimate.units == 2 and estimate.first.cases == 2 * 9
    assert estimate.cases == 2 * 40                            # at most: the budget of each refinement
    # the widest coarse interval on each axis, one after the other: S from 10 to 40 is log 4 = 14.5
    # tolerances, 4 halvings; psi_bar from 0.3 to 0.5 is 4 tolerances, 2 halvings
    assert sum(s.rounds for s in estimate.stages[1:]) == settings.stages_needed() - 1 == 4 + 2
    assert estimate.widest == 18 and estimate.suggested_ranks() <= 19   # later widths are not known (19: 18 compute)


def test_step_cost_is_measured_once_per_kind_of_step(tmp_path):
    study = study_from_toml(TINY.format(name="c", output=tmp_path / "c.h5")
                            + "[sweep]\nshear_rate = [10, 20]\npsi_bar = [0.3, 0.5]\n")
    said = []
    cost = StepCost(steps=20, announce=said.append)
    seconds = [cost(c.case) for c in study.cases]
    assert all(s > 0 for s in seconds)
    # dt is 1e-3 in every case and every 10th step samples: one kind, timed once
    assert len(cost.measured) == 1 and len(said) == 1 and "N = 32" in said[0]
    assert len(set(seconds)) == 1


def test_each_n_is_timed_once_whatever_the_cases_sample():
    """Cases that sample and snapshot at different shares of their steps share one timing of their N: a
    case's cost is the bare step plus its shares of a sample's and a snapshot's cost."""
    said = []
    cost = StepCost(steps=20, announce=said.append)
    base = Case(Physics(shear_rate=10.0, psi_bar=0.3), Numerics(N=32, dt=1e-3),
                RunControl(t_end=0.05, sample_interval=1e-3, snapshot_interval=0.01, checkpoint_interval=0.05))
    every = [dataclasses.replace(base, run=dataclasses.replace(base.run, sample_interval=k * 1e-3,
                                                               snapshot_interval=m * 1e-3))
             for k, m in ((1, 1), (1, 10), (4, 10), (10, 50))]
    seconds = [cost(c) for c in every]
    assert len(said) == 1 and len(cost.measured) == 1 and "N = 32" in said[0]
    parts = cost.measured[StepCost.kind_of(base)]
    assert parts.step > 0 and parts.sample >= 0 and parts.snapshot >= 0
    assert seconds == [parts.cost(*StepCost.shares(c)) for c in every]
    assert seconds == sorted(seconds, reverse=True)            # fewer writes never cost more


def test_plan_on_the_command_line_and_its_slurm_script(tmp_path):
    study_file = tmp_path / "p.toml"
    study_file.write_text(TINY.format(name="p", output=tmp_path / "p.h5")
                          + "[sweep]\nshear_rate = [10, 20]\npsi_bar = [0.3, 0.5]\n")
    script = tmp_path / "job.sh"
    result = hpcves("campaign", study_file, "--plan", "--slurm", script)
    assert result.returncode == 0, result.stderr
    assert "timing a step at N = 32" in result.stderr
    assert "| in all | 4 |" in result.stdout and "(suggested)" in result.stdout
    assert "rank 0 alone: laying out the 4 cases" in result.stdout and "hpcves analyze afterwards" in result.stdout
    assert "cases a rank at the suggestion" in result.stdout
    ranks = int(result.stdout.split("suggested: ")[1].split()[0])
    assert not (tmp_path / "p.h5").exists()                     # a plan runs nothing
    text = script.read_text()
    assert f"#SBATCH --ntasks={ranks}\n" in text and "#SBATCH --account=CHANGE_ME" in text
    # memory: the measured model of a rank at the study's N (32), compiling its engine, with the margin
    assert f"#SBATCH --mem-per-cpu={mem_per_cpu(rank_bytes(32, False))}M\n" in text
    assert 500 <= mem_per_cpu(rank_bytes(32, False)) <= 700
    assert re.search(r"^MAX_JOBS=(\d+)$", text, re.M) and "{{" not in text
    assert f"STUDY={study_file.resolve()}\n" in text and f"OUT={(tmp_path / 'p.h5').resolve()}\n" in text
    assert os.stat(script).st_mode & stat.S_IXUSR
    assert subprocess.run(["bash", "-n", str(script)]).returncode == 0
    wrong = hpcves("campaign", study_file, "--slurm", script)
    assert wrong.returncode == 2 and "--slurm goes with --plan" in wrong.stderr
    nowhere = hpcves("campaign", study_file, "--plan", "--slurm", tmp_path / "no" / "job.sh")
    assert nowhere.returncode == 2 and "does not exist" in nowhere.stderr and "timing" not in nowhere.stderr


def test_the_slurm_chain_keeps_a_successor_waiting_while_work_is_left(tmp_path):
    """The script with stand-ins for srun, sbatch and scancel. Each job submits its successor first
    (afterany: it starts however this job ends -- a chain whose job was killed before its last lines
    stopped, since only those lines resubmitted); a job that finds the campaign complete cancels it;
    idle jobs in a row and the cap stop the chain; messages name the script as submitted, not $0."""
    study_file = tmp_path / "w.toml"
    output = tmp_path / "w.h5"
    study_file.write_text(TINY.format(name="w", output=output) + "[sweep]\nshear_rate = [10, 20]\n")
    script = tmp_path / "job.sh"
    assert hpcves("campaign", study_file, "--plan", "--slurm", script).returncode == 0
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    submitted, cancelled = tmp_path / "submitted", tmp_path / "cancelled"
    (bin_dir / "sbatch").write_text(f'#!/bin/bash\necho "$@" >> {submitted}\necho 4242\n')
    (bin_dir / "scancel").write_text(f'#!/bin/bash\necho "$@" >> {cancelled}\n')
    (bin_dir / "srun").write_text("#!/bin/bash\n" + ('shift\nexec "$@"\n'))      # drop --kill-on-bad-exit
    (bin_dir / "idle-srun").write_text("#!/bin/bash\nexit 0\n")                    # a job cut before it ran
    (bin_dir / "killed-srun").write_text("#!/bin/bash\nkill -9 $PPID\n")           # the job dies mid-way
    for f in bin_dir.iterdir():
        f.chmod(0o755)
    env = dict(os.environ, PATH=f"{bin_dir}:{os.environ['PATH']}", SLURM_JOB_ID="4241")

    def job(text: str, name: str):
        path = tmp_path / name                              # slurmd's spooled copy: $0 is not the script
        path.write_text(text)
        return subprocess.run(["bash", str(path)], env=env, capture_output=True, text=True, cwd=tmp_path,
                              timeout=300)

    def lines(path):
        return path.read_text().splitlines() if path.exists() else []

    successor = f"--parsable --dependency=afterany:4241 {script}"

    # the campaign file exists, no case has run (stopped at once): work is left
    run_campaign(load_study(study_file), output, stop_flag=lambda: True)
    text = script.read_text()
    idle = text.replace("srun --kill-on-bad-exit=0", "idle-srun --kill-on-bad-exit=0")
    first = job(idle, "spool1")
    assert first.returncode == 0, first.stderr
    assert "work left: job 4242 continues (job 2 of at most" in first.stdout, first.stdout
    assert lines(submitted) == [successor] and lines(cancelled) == []

    # a job killed before its last lines: its successor was submitted before it ran
    killed = job(text.replace("srun --kill-on-bad-exit=0", "killed-srun --kill-on-bad-exit=0"), "spool2")
    assert killed.returncode != 0
    assert lines(submitted) == [successor] * 2 and lines(cancelled) == []

    # the two jobs so far found the campaign as it was: the next one stops the chain at once -- a job
    # that can never progress (a creation longer than the job) would run forever
    stopped = job(idle, "spool3")
    assert stopped.returncode == 1 and "the last 2 jobs of this chain advanced nothing" in stopped.stderr, \
        stopped.stderr
    assert f"sbatch {script} once the cause is fixed" in stopped.stderr and "spool" not in stopped.stderr
    assert len(lines(submitted)) == 2                                    # the stopping job submitted none
    (tmp_path / "w.h5.idle_jobs").unlink()

    # the chain's cap: the job that reaches it submits no successor and says how to go on
    capped = job(re.sub(r"^MAX_JOBS=\d+$", "MAX_JOBS=4", idle, flags=re.M), "spool4")
    assert capped.returncode == 0, capped.stderr
    assert "this was job 4 of at most 4" in capped.stderr and f"then sbatch {script}" in capped.stderr, \
        capped.stderr
    assert len(lines(submitted)) == 2

    # the job that completes the campaign cancels its waiting successor and clears the chain's files
    (tmp_path / "w.h5.jobs").write_text("1\n")
    (tmp_path / "w.h5.idle_jobs").unlink()
    done = job(text, "spool5")
    assert done.returncode == 0, done.stderr
    assert "status: complete" in done.stdout and "continues" not in done.stdout
    assert lines(submitted)[-1] == successor and lines(cancelled) == ["4242"]
    assert not any(tmp_path.glob("w.h5.*_*")) and not (tmp_path / "w.h5.jobs").exists()


def test_a_site_template_without_the_signal_line_is_refused_before_the_timing(tmp_path):
    study_file = tmp_path / "s.toml"
    study_file.write_text(TINY.format(name="s", output=tmp_path / "s.h5") + "[sweep]\nshear_rate = [10, 20]\n")
    site = tmp_path / "site.sh"
    site.write_text("#!/bin/bash\n#SBATCH --ntasks={{ ranks }}\nsrun {{ hpcves }} campaign {{ study_file }}\n")
    result = hpcves("campaign", study_file, "--plan", "--slurm", tmp_path / "job.sh", "--slurm-template", site)
    assert result.returncode == 2 and "timing" not in result.stderr, result.stderr
    assert "no '#SBATCH --signal=TERM@{{ signal_seconds }}' line" in result.stderr, result.stderr
    assert not (tmp_path / "job.sh").exists()


def test_a_site_brings_its_own_batch_script_template(tmp_path):
    """signac-flow users bring their own template; ours had to be edited after writing. Placeholders
    are filled in, an unknown one is refused (with the near miss) before the step is timed."""
    study_file = tmp_path / "s.toml"
    study_file.write_text(TINY.format(name="s", output=tmp_path / "s.h5") + "[sweep]\nshear_rate = [10, 20]\n")
    site = tmp_path / "site.sh"
    site.write_text("#!/bin/bash\n#SBATCH --account=phys42 --qos=long\n#SBATCH --ntasks={{ ranks }}\n"
                    "#SBATCH --signal=TERM@{{ signal_seconds }}\n"
                    "#SBATCH --mem-per-cpu={{mem_per_cpu}}\n#SBATCH --time={{ time }}\n"
                    "module load mpi/site\nsrun {{ hpcves }} campaign {{ study_file }} --out {{ output }} --resume\n")
    script = tmp_path / "job.sh"
    result = hpcves("campaign", study_file, "--plan", "--slurm", script, "--slurm-template", site, "--max-jobs", 7)
    assert result.returncode == 0, result.stderr
    assert f"from {site}" in result.stdout and "at most 7 jobs" in result.stdout
    text = script.read_text()
    assert "--account=phys42 --qos=long" in text and "module load mpi/site" in text and "{{" not in text
    assert f"--mem-per-cpu={mem_per_cpu(rank_bytes(32, False))}M" in text
    assert f"campaign {study_file.resolve()} --out {(tmp_path / 's.h5').resolve()} --resume" in text
    site.write_text("#SBATCH --ntasks={{ rank }}\n#SBATCH --signal=TERM@{{ signal_seconds }}\n")
    wrong = hpcves("campaign", study_file, "--plan", "--slurm", script, "--slurm-template", site)
    assert wrong.returncode == 2 and "timing" not in wrong.stderr
    assert "unknown placeholder {{ rank }} (did you mean {{ ranks }}?)" in wrong.stderr
    alone = hpcves("campaign", study_file, "--plan", "--slurm-template", site)
    assert alone.returncode == 2 and "--slurm-template goes with --plan --slurm" in alone.stderr


def test_a_plan_stopped_by_sigterm_leaves_no_scratch_file(tmp_path):
    """--plan times a step in a scratch directory; killed by SIGTERM (`timeout`, a batch system) while
    timing, it left the directory with its file behind (two of 22 GB each once filled a disk)."""
    import signal
    import time

    study_file = tmp_path / "slow.toml"
    study_file.write_text(TINY.format(name="slow", output=tmp_path / "slow.h5").replace("N = 32", "N = 1024")
                          + "[sweep]\nshear_rate = [10, 20]\n")
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    process = start_job(None, "campaign", study_file, "--plan", env=dict(mpi_env(), TMPDIR=str(scratch)))
    deadline = time.monotonic() + 120
    while not any(scratch.glob("hpcves-timing-*/*.h5")):                # timing has begun
        assert process.poll() is None and time.monotonic() < deadline, process.communicate()
        time.sleep(0.05)
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 128 + signal.SIGTERM, stderr
    assert "Traceback" not in stderr and list(scratch.iterdir()) == [], (stderr, list(scratch.iterdir()))


def test_docs_cluster_lists_every_placeholder_a_template_may_use():
    from pathlib import Path

    from hpcves.campaign.slurm import PLACEHOLDERS, TEMPLATE, read_template

    text = (Path(__file__).resolve().parents[1] / "docs" / "cluster.md").read_text()
    assert all(f"`{{{{ {name} }}}}`" in text for name in PLACEHOLDERS)
    assert read_template(None) == TEMPLATE.read_text()                # the default passes its own check
