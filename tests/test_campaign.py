"""Campaigns: one file for every case, failures recorded, resume after SIGKILL, clean stop on SIGTERM.

The MPI tests start real jobs (``mpirun -n 2`` and an oversubscribed ``-n 3``)
and compare every recorded number bitwise with an uninterrupted serial run.
"""
import io
import json
import os
import re
import shutil
import signal

import h5py
import numpy as np
import pytest

from conftest import tiny_study
from conftest import write_tiny_study as write_study
from hpcves.campaign import access
from hpcves.campaign.driver import run_campaign
from hpcves.campaign.study import study_from_toml
from hpcves.cli.terminal import CampaignProgress
from hpcves.errors import FileFormatError
from hpcves.files.lock import CampaignLock
from hpcves.model.params import ConfigError
from hpcves.run import runner
from hpcves.run.blocks import QUANTITIES
from hpcves.run.store import FAILED, FINISHED, INTERRUPTED, CaseStore, superblock_version
from jobs import (
    HANG,
    MPIRUN,
    assert_same_results,
    case_statuses,
    case_store,
    case_view,
    freeze_when,
    hpcves,
    job_pids,
    mpi_env,
    running_cases,
    start_job,
    thaw,
    wait_until,
)

needs_mpi = pytest.mark.skipif(MPIRUN is None, reason="no mpirun")

# `make test` runs each MPI behaviour once, with one rank count and one I/O mode; the other
# combinations carry the `faults` marker and run in `make faults` (relay at 3 ranks is also
# what test_faults.py kills at exact moments in `make test`).
more = pytest.mark.faults


def statuses(path):
    return case_statuses(path)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The tiny study run serially in this process, uninterrupted (t_end = 0.3)."""
    tmp = tmp_path_factory.mktemp("reference")
    path, output = write_study(tmp, t_end=0.3)
    summary = run_campaign(study_from_toml(path.read_text()), output)
    assert summary.exit_status == 0
    return output


# ---------------------------------------------------------------------- in one process
def test_a_campaign_case_is_the_single_run_of_that_case(tmp_path, reference):
    from hpcves.run import runner

    study = study_from_toml(write_study(tmp_path, t_end=0.3)[0].read_text())
    with h5py.File(tmp_path / "single.h5", "w") as h5:
        store = CaseStore.create(h5, study.cases[3].case)
        assert runner.run(store, h5.flush).status == FINISHED
    with h5py.File(reference, "r") as ref, h5py.File(tmp_path / "single.h5", "r") as one:
        a, b = case_store(ref, "0003").timeseries(), CaseStore.open(one).timeseries()
        assert len(a["t"]) == 61
        for key in a:
            assert np.array_equal(a[key], b[key], equal_nan=True), key


def test_layout_and_status_command(reference):
    with h5py.File(reference, "r") as f:
        assert f.attrs["format"] == "hpcves-campaign" and f.attrs["n_cases"] == 4
        assert list(f["index/shear_rate"][:]) == [40, 40, 80, 80]
        assert list(f["index/psi_bar"][:]) == [0.3, 0.5, 0.3, 0.5]
        g = case_view(f, "0002")
        assert g.attrs["physics.shear_rate"] == 80.0 and g.attrs["physics.psi_bar"] == 0.3
        assert int(g["status"][()]) == FINISHED
        assert {"checkpoint/slot0/meta", "checkpoint/slot1/meta"} <= set(g.names())
        assert f["index/block"][2] == 0 and f["index/row"][2] == 2 and f["blocks/0/status"].shape == (4,)
        # HDF5 1.8's superblock (no open-for-writing mark: read while written), 1.10's object formats
        assert h5py.h5o.get_info(f["blocks/0/timeseries/series"].id).hdr.version == 2
        assert f.attrs["format_version"] == 3 and f["blocks/0/timeseries/series"].shape[::2] == (4, len(QUANTITIES))
    assert superblock_version(reference) == 2
    result = hpcves("status", reference)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].split()[:4] == ["case", "shear_rate", "psi_bar", "status"]
    assert lines[3].split()[:5] == ["0002", "80", "0.3", "finished", "0.3"]
    assert "4 cases: 4 finished" in lines[-1] and lines[-1].endswith("; complete")
    result = hpcves("status", reference, "--json")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["complete"] is True and report["exit_status"] == 0 and report["totals"] == {"finished": 4}
    assert [r["case"] for r in report["rows"]] == ["0000", "0001", "0002", "0003"]
    assert report["rows"][2]["shear_rate"] == 80 and report["rows"][2]["status"] == "finished"


def test_a_case_that_raises_is_recorded_and_retried(tmp_path, monkeypatch, reference):
    path, output = write_study(tmp_path, t_end=0.3)
    study = study_from_toml(path.read_text())
    real_run = runner.run

    def broken(store, *args, **kwargs):
        if store.where.endswith("0001"):
            raise RuntimeError("injected failure")
        return real_run(store, *args, **kwargs)

    monkeypatch.setattr(runner, "run", broken)
    summary = run_campaign(study, output)
    assert summary.exit_status == 1
    assert summary.failed == (("0001", "RuntimeError: injected failure"),)
    assert statuses(output) == {"0000": FINISHED, "0001": FAILED, "0002": FINISHED, "0003": FINISHED}
    with h5py.File(output, "r") as f:
        store = case_store(f, "0001")
        assert "injected failure" in store.traceback and "in broken" in store.traceback

    monkeypatch.setattr(runner, "run", real_run)
    shown = io.StringIO()                                  # the progress line counts what ended before
    display = []

    def announce(text, n_cases, ended_before):
        if n_cases is not None:
            display[:] = [CampaignProgress(n_cases, ended_before, stream=shown)]

    again = run_campaign(study, output, resume=True, announce=announce,     # failed cases are left alone
                         display=lambda stage: display and display[0](stage))
    assert again.ran == () and again.exit_status == 1
    assert "4/4 cases | 0 running | 1 failed | 100 %" in shown.getvalue(), shown.getvalue()
    retried = run_campaign(study, output, resume=True, retry_failed=True)
    assert [r.case_id for r in retried.ran] == ["0001"] and retried.exit_status == 0
    assert_same_results(output, reference)


def test_a_grid_grows_by_new_sweep_values_into_its_file(tmp_path, reference):
    """A finished study given a new shear rate resumes into the same file: its cases keep their ids and
    every number bit for bit, the new ones follow (and equal a fresh run of the grown study's cases);
    a sweep value taken away, or a parameter changed, is refused by name."""
    from jobs import _same, results

    output = tmp_path / "tiny.h5"
    shutil.copy(reference, output)
    grown_toml, _ = write_study(tmp_path, t_end=0.3, shear="[40, 60, 80]", output=output)
    grown = study_from_toml(grown_toml.read_text())
    said = []
    summary = run_campaign(grown, output, resume=True, announce=lambda text, *_: said.append(text))
    assert summary.exit_status == 0 and sorted(r.case_id for r in summary.ran) == ["0004", "0005"]
    assert any("the study grew: 2 new cases (shear_rate += 60)" in line for line in said), said
    before, after = results(reference), results(output)
    for case_id in ("0000", "0001", "0002", "0003"):                    # kept, bit for bit
        assert _same(before[case_id], after[case_id]), case_id
    with h5py.File(output, "r") as f:
        index = {k: f["index"][k][:] for k in ("shear_rate", "psi_bar")}
        assert list(index["shear_rate"]) == [40, 40, 80, 80, 60, 60] and f.attrs["n_cases"] == 6
        assert f.attrs["campaign_toml"] == grown_toml.read_text()
    # the new cases are the grown study's, as a fresh run computes them
    fresh = tmp_path / "fresh.h5"
    assert run_campaign(study_from_toml(grown_toml.read_text().replace(str(output), str(fresh))), fresh,
                        ).exit_status == 0
    mine = results(fresh)
    for grown_id, fresh_id in (("0004", "0002"), ("0005", "0003")):
        a = {k: v for k, v in after[grown_id].items() if k != "attrs"}
        b = {k: v for k, v in mine[fresh_id].items() if k != "attrs"}
        assert _same(a, b), (grown_id, fresh_id)
    # once grown, the same study file resumes with nothing to do and nothing changed
    said.clear()
    again = run_campaign(grown, output, resume=True, announce=lambda text, *_: said.append(text))
    assert again.ran == () and not any("grew" in line for line in said)
    assert _same(results(output), after)
    # a value taken away is not growth
    shrunk = study_from_toml(write_study(tmp_path, t_end=0.3, shear="[40, 60]", output=output)[0].read_text())
    with pytest.raises(FileFormatError, match=r"its case 0002 \(shear_rate = 80, psi_bar = 0.3\) is not in the study"):
        run_campaign(shrunk, output, resume=True)


def test_files_that_are_not_this_campaign_are_refused(tmp_path, reference):
    path, output = write_study(tmp_path, t_end=0.3)
    study = study_from_toml(path.read_text())
    shutil.copy(reference, output)
    with pytest.raises(FileFormatError, match="exists already; use --resume"):
        run_campaign(study, output)
    other = study_from_toml(write_study(tmp_path, name="other", t_end=0.2)[0].read_text())
    with pytest.raises(FileFormatError, match="belongs to study 'tiny'"):
        run_campaign(other, output, resume=True)
    changed = study_from_toml(write_study(tmp_path, t_end=0.2)[0].read_text())
    with pytest.raises(FileFormatError, match=r"a different version of study 'tiny': case 0000 \(shear_rate = 40, "
                                          r"psi_bar = 0.3\): run.t_end: 0.3 -> 0.2 changed, which changes the cases"):
        run_campaign(changed, output, resume=True)

    single = tmp_path / "single.h5"
    with h5py.File(single, "w") as h5:
        CaseStore.create(h5, study.cases[0].case)
    with pytest.raises(FileFormatError, match="single-run file"):
        run_campaign(study, single, resume=True)

    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(reference.read_bytes()[:5000])
    with pytest.raises(FileFormatError, match="truncated.h5: .*(corrupt|truncated|damaged|readable)"):
        run_campaign(study, truncated, resume=True)
    garbage = tmp_path / "garbage.h5"
    garbage.write_bytes(os.urandom(4096))
    with pytest.raises(FileFormatError, match="not a readable HDF5 file"):
        run_campaign(study, garbage, resume=True)


def test_the_command_line_gives_one_line_for_bad_files(tmp_path, reference):
    path, _ = write_study(tmp_path, t_end=0.3, output=reference)
    result = hpcves("campaign", path, "--out", tmp_path / "x.h5", "--retry-failed")
    assert result.returncode == 2 and "--retry-failed goes with --resume" in result.stderr
    garbage = tmp_path / "garbage.h5"
    garbage.write_bytes(b"\0" * 100)
    result = hpcves("campaign", path, "--out", garbage, "--resume")
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.strip().splitlines() == [f"Error: {garbage}: not a readable HDF5 file (corrupt or truncated?)"]
    result = hpcves("status", garbage)
    assert result.returncode == 2 and "not a readable HDF5 file" in result.stderr


def test_without_mpirun_the_command_runs_every_case_itself(tmp_path, reference):
    path, output = write_study(tmp_path, t_end=0.3)
    result = hpcves("campaign", path)
    assert result.returncode == 0, result.stderr
    assert "1 rank, serial HDF5" in result.stderr and "4 finished" in result.stdout
    assert_same_results(output, reference)
    again = hpcves("campaign", path, "--resume")
    assert again.returncode == 0 and "0 to run" in again.stderr


def test_a_second_campaign_on_the_same_file_is_refused(tmp_path):
    path, output = write_study(tmp_path)
    lock = CampaignLock(output).acquire()
    try:
        result = hpcves("campaign", path)
    finally:
        lock.release()
    assert result.returncode == 2, result.stderr
    assert "is writing this file" in result.stderr and f"pid {os.getpid()}" in result.stderr
    assert not output.exists()


RANKS_RAISE = """
import sys
from mpi4py import MPI
from hpcves.campaign.driver import run_campaign
from hpcves.campaign.study import load_study
rank = MPI.COMM_WORLD.Get_rank()
try:
    run_campaign(load_study(sys.argv[1]), sys.argv[2], MPI.COMM_WORLD)
    raised = "nothing"
except Exception as exc:
    raised = type(exc).__name__
with open(f"{sys.argv[3]}.{rank}", "w") as f:       # a file a rank: mpirun interleaves the ranks' stdout
    f.write(raised)
"""


@needs_mpi
def test_every_rank_raises_the_error_rank_0_met_with_its_type(tmp_path):
    """Rank 0 finds the file locked (LockError); the other ranks raised FileFormatError instead."""
    import subprocess
    import sys

    path, output = write_study(tmp_path)
    script = tmp_path / "ranks.py"
    script.write_text(RANKS_RAISE)
    lock = CampaignLock(output).acquire()
    try:
        result = subprocess.run([MPIRUN, "-n", "2", sys.executable, str(script), str(path), str(output),
                                 str(tmp_path / "raised")], capture_output=True, text=True, timeout=HANG,
                                env=mpi_env())
    finally:
        lock.release()
    raised = [(tmp_path / f"raised.{rank}").read_text() if (tmp_path / f"raised.{rank}").exists() else None
              for rank in (0, 1)]
    assert raised == ["LockError", "LockError"], (raised, result.stdout, result.stderr)


# ---------------------------------------------------------------------- real MPI jobs
def wait_for_checkpoints(output, job, count=2):
    """Until ``count`` cases are running with a valid checkpoint (so that a kill lands mid-run)."""
    def ready():
        assert job.poll() is None, job.communicate()
        return len(running_cases(output, checkpointed=True)) >= count
    wait_until(ready, f"{count} cases run with a checkpoint")


ACCESS = {"mpio": "parallel HDF5", "relay": "HDF5 through rank 0"}


@needs_mpi
@pytest.mark.parametrize("n, io", [(2, "mpio"), pytest.param(3, "mpio", marks=more),
                                   pytest.param(2, "relay", marks=more), (3, "relay")])
def test_mpi_campaign_completes_and_matches_the_serial_run(tmp_path, reference, n, io):
    path, output = write_study(tmp_path, t_end=0.3)
    result = hpcves("campaign", path, "--io", io, n=n)
    assert result.returncode == 0, result.stderr
    assert f"{n} ranks, {ACCESS[io]}" in result.stderr
    assert_same_results(output, reference)


def test_without_mpi_in_h5py_the_ranks_write_through_rank_0(monkeypatch):
    import h5py

    class NoMPI:
        mpi = False

    monkeypatch.setattr(h5py, "get_config", lambda: NoMPI())
    assert access.choose_io("auto", 2) == "relay"
    assert access.choose_io("auto", 1) == "serial"
    with pytest.raises(ConfigError, match="built without MPI"):
        access.choose_io("mpio", 2)


@needs_mpi
@pytest.mark.parametrize("n, io", [(2, "mpio"), pytest.param(3, "mpio", marks=more),
                                   pytest.param(3, "relay", marks=more)])
def test_sigkill_of_the_whole_job_then_resume_is_bitwise_identical(tmp_path, n, io):
    # t_end = 2: on the compiled step cases of 0.8 could end between two polls of a loaded machine
    path, output = write_study(tmp_path, t_end=2.0, checkpoint=0.02, shear="[20, 40, 80]")
    job = start_job(n, "campaign", path, "--quiet", "--io", io)
    wait_for_checkpoints(output, job, count=n)
    for pid in job_pids(job.pid):
        os.kill(pid, signal.SIGKILL)
    job.communicate()
    states = statuses(output)
    assert 1 in states.values(), states            # killed mid-run: cases left "running"
    result = hpcves("campaign", path, "--resume", "--io", io, n=n)
    assert result.returncode == 0, result.stderr
    assert "from a checkpoint" in result.stderr
    assert set(statuses(output).values()) == {FINISHED}

    (tmp_path / "fresh").mkdir()
    fresh, fresh_output = write_study(tmp_path / "fresh", t_end=2.0, checkpoint=0.02, shear="[20, 40, 80]")
    assert run_campaign(study_from_toml(fresh.read_text()), fresh_output).exit_status == 0
    assert_same_results(output, fresh_output)


@needs_mpi
@pytest.mark.parametrize("io", ["relay", pytest.param("mpio", marks=more)])
def test_series_longer_than_a_chunk_are_written_alike_by_every_mode_and_resume_bitwise(tmp_path, io):
    """Campaign format 3 splits a case's packed series into chunks of whole rows (at most 256 KiB: 1424
    samples): a kill under relay and the resume, and a run under mpio (`make faults`), write what one
    process writes."""
    # t_end = 6: cases long enough (~1 s on the compiled step) that the kill finds both running
    path, serial = write_study(tmp_path, t_end=6.0, checkpoint=0.4, shear="[40]", sample=0.001)
    assert run_campaign(study_from_toml(path.read_text()), serial).exit_status == 0
    with h5py.File(serial, "r") as f:
        series = f["blocks/0/timeseries/series"]
        assert series.shape[1] > 1600 and series.chunks[1] < 1600      # two chunks a case
    (tmp_path / io).mkdir()
    study, output = write_study(tmp_path / io, t_end=6.0, checkpoint=0.4, shear="[40]", sample=0.001)
    if io == "relay":
        job = start_job(3, "campaign", study, "--quiet", "--io", io)

        def running_with_a_checkpoint():  # one case, not both: under load the two overlapped too briefly
            assert job.poll() is None, job.communicate()
            return len(running_cases(output, checkpointed=True)) >= 1
        freeze_when(job, running_with_a_checkpoint, "a case runs with a checkpoint")   # held there, then killed
        for pid in job_pids(job.pid):
            os.kill(pid, signal.SIGKILL)
        job.communicate()
        assert 1 in statuses(output).values()
    result = hpcves("campaign", study, "--quiet", "--io", io, *(("--resume",) if io == "relay" else ()), n=3)
    assert result.returncode == 0, result.stderr
    assert_same_results(output, serial)
    check = hpcves("status", "--check", output)
    assert check.returncode == 0, check.stdout + check.stderr


@needs_mpi
@pytest.mark.parametrize("io", [pytest.param("mpio", marks=more), "relay"])
def test_sigterm_checkpoints_every_running_case_and_exits_0(tmp_path, io):
    # only the stop writes checkpoints; a sample every step makes the first flush come after 512 steps.
    # Two cases, one a rank, of 20000 steps: the state waited for (both ranks past their first flush)
    # holds for most of a case. At t_end = 3 with four cases a fast CI machine ran the whole campaign
    # in 2 s, between two polls of the state.
    path, output = write_study(tmp_path, t_end=20.0, checkpoint=100.0, sample=1e-3, shear="[40]")

    def both_ranks_sampling():          # a state, not a time: each rank runs a case that has taken steps
        assert job.poll() is None, job.communicate()
        return len(running_cases(output, sampled=True)) == 2
    job = start_job(2, "campaign", path, "--io", io)
    frozen = freeze_when(job, both_ranks_sampling, "both ranks run a case with samples written")
    for pid in frozen:                                 # what SLURM does: every task gets the signal
        os.kill(pid, signal.SIGTERM)
    thaw(frozen)
    out, err = job.communicate(timeout=HANG)
    assert job.returncode == 0, err                    # (a stop slower than stop_timeout would abort: not 0)
    assert "stopping" in err and "continue with --resume" in err
    interrupted = [c for c, s in statuses(output).items() if s == INTERRUPTED]
    assert len(interrupted) == 2, statuses(output)
    with h5py.File(output, "r") as f:
        for case_id in interrupted:
            state, _, _ = case_store(f, case_id).read_checkpoint()
            assert state.step > 0
    result = hpcves("campaign", path, "--resume", n=2)
    assert result.returncode == 0, result.stderr
    assert set(statuses(output).values()) == {FINISHED}


@needs_mpi
@pytest.mark.parametrize("io", ["mpio", pytest.param("relay", marks=more)])
def test_a_diverging_case_fails_alone_under_mpi(tmp_path, io):
    path, output = write_study(tmp_path, t_end=0.2, shear="[40, 20000]")   # N = 32 cannot follow S = 20000
    result = hpcves("campaign", path, "--io", io, n=2)
    assert result.returncode == 1, result.stderr
    assert statuses(output) == {"0000": FINISHED, "0001": FINISHED, "0002": FAILED, "0003": FAILED}
    assert "case 0002 failed: diverged" in result.stderr
    # rank 0's log record as it happened, with its rank (cli.terminal.TerminalLog)
    assert re.search(r"^\[rank 0\] case 0002 \(shear_rate = 20000, psi_bar = 0.3\) failed on rank [01]: diverged",
                     result.stderr, re.M), result.stderr
    status = hpcves("status", output)
    assert "2 finished, 2 failed" in status.stdout.splitlines()[-1]
    assert status.returncode == 1 and "complete, 2 failed (--resume --retry-failed" in status.stdout


LIMIT_STUDY = """
[campaign]
name = "limit"
output = "{output}"
t_end = 3.5
[physics]
psi_bar = 0.48
shear_rate = 5.0
bending_law = "linear"
[numerics]
N = 128
rtol = 1e-2
[run]
sample_interval = 0.02
snapshot_interval = 0.5
checkpoint_interval = 3.5
[sweep]
excess_length = [0.194, 1.3]
"""


def test_a_case_past_the_linear_laws_range_ends_at_the_model_limit_not_as_failed(tmp_path):
    # Delta = 1.3 under the linear bending law: the soft phase sharpens a tip until psi = 1.08 and
    # the spectral tail stops the run between t = 2.7 and 2.9 (the moment follows rounding: OpenBLAS's
    # SkylakeX kernels give 2.74, its Haswell ones 2.92; test_stepcontrol.py); Delta = 0.194 runs through
    from hpcves.reports.analyze import analyze
    from hpcves.run.store import MODEL_LIMIT

    output = tmp_path / "limit.h5"
    study = study_from_toml(LIMIT_STUDY.format(output=output))
    summary = run_campaign(study, output)
    assert statuses(output) == {"0000": FINISHED, "0001": MODEL_LIMIT}
    assert summary.exit_status == 0 and summary.failed == ()
    assert summary.counts["model limit"] == 1 and summary.counts["failed"] == 0
    again = run_campaign(study, output, resume=True, retry_failed=True)    # an outcome: never rerun
    assert again.ran == () and again.exit_status == 0
    status = hpcves("status", output)
    assert status.returncode == 0 and "1 finished, 1 model limit" in status.stdout.splitlines()[-1]
    stopped = re.search(r"model limit  (\d(?:\.\d+)?) / 3\.5", status.stdout)      # 2.74, 2.9, ...: the machine's
    assert stopped and 2.6 < float(stopped[1]) < 3.5, status.stdout
    report = analyze(output, tmp_path / "out", case_figures=False)
    limit = next(r for r in report.rows if r["case"] == "0001")
    assert limit["regime"] == "model limit" and limit["reason"].startswith(f"stopped at t = {stopped[1]}")
    assert ": psi in [" in limit["reason"]
    assert report.counts()["model limit"] == 1


def test_a_stage_with_more_ranks_than_cases_says_how_many_idle():
    """`mpirun -n 4` on 2 cases idled 2 ranks without a word."""
    from hpcves.campaign.stages import stage_line
    from hpcves.campaign.study import study_from_toml

    study = study_from_toml(tiny_study("idle.h5", "idle", shear="[5.0]"))          # x psi_bar = [0.3, 0.5]: 2 cases
    todo = [(c.case_id, False) for c in study.cases]
    assert len(todo) == 2
    assert "2 of the 4 ranks idle: more ranks than cases" in stage_line(study, {}, todo, 0, size=4)
    assert "idle" not in stage_line(study, {}, todo, 0, size=2)
    assert "idle" not in stage_line(study, {}, todo, 0)
