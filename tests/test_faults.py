"""Campaign files that survive every fault: kills at any moment (creation included), second writers
through other names, full disks, damaged files, readers of a live file (issue 14).

Every test waits for a state (a file, a status, a frozen job), never for a time. Full-disk tests
mount a small tmpfs and are skipped, with the reason, where the machine does not allow that.
"""
import hashlib
import os
import signal
import subprocess
import time

import h5py
import numpy as np
import pytest

from conftest import tiny_study, write_tiny_study
from hpcves.campaign import driver, structure
from hpcves.campaign.driver import run_campaign
from hpcves.campaign.study import study_from_toml
from hpcves.files.atomic import StorageError
from hpcves.run.store import FINISHED, RUNNING, CaseStore
from jobs import (
    MPIRUN,
    assert_same_results,
    case_statuses,
    case_view,
    freeze_when,
    hpcves,
    kill_job,
    running_cases,
    start_job,
    thaw,
    wait_until,
    writing_format,
)

needs_mpi = pytest.mark.skipif(MPIRUN is None, reason="no mpirun")

def write_study(directory, **settings):
    """The tiny test campaign (conftest.tiny_study) named "faults", checkpointing every 0.02 by default."""
    return write_tiny_study(directory, **{"name": "faults", "checkpoint": 0.02, **settings})


def reference_of(path, directory):
    """The same study run uninterrupted, serially in this process, into ``directory``."""
    text = path.read_text()
    study = study_from_toml(text)
    output = directory / "reference.h5"
    assert run_campaign(study, output).exit_status == 0
    return output


def one_line(result):
    """The single line a refusal prints on stderr (and no traceback)."""
    assert "Traceback" not in result.stderr, result.stderr
    lines = [line for line in result.stderr.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error: "), result.stderr
    return lines[0]


def error_line(result):
    """The one ``Error:`` line a command ends with (progress lines may come before it), no traceback."""
    assert "Traceback" not in result.stderr, result.stderr
    lines = [line for line in result.stderr.strip().splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("Error: ")]
    assert len(errors) == 1 and lines[-1] == errors[0], result.stderr
    return errors[0]


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


MANY = "{ linspace = [10, 400, 40] }"          # 40 x 3 = 120 cases: creating them takes a while


# ---------------------------------------------------------------------- 1. a kill while the file is created
# a kill at a random moment of creation, in make faults (both modes); make test has the deterministic
# one below, which always lands while the file is laid out
@needs_mpi
@pytest.mark.faults
@pytest.mark.parametrize("io", ["mpio", "relay"])
def test_a_kill_while_the_file_is_created_leaves_nothing_that_blocks_a_resume(tmp_path, io):
    path, output = write_study(tmp_path / "job", t_end=0.002, shear=MANY, psi="[0.3, 0.4, 0.5]")
    partial = output.with_name(output.name + ".partial")
    job = start_job(2, "campaign", path, "--quiet", "--io", io)
    wait_until(lambda: partial.exists() or output.exists(), "the file's creation has begun")
    kill_job(job)
    status = hpcves("status", output)
    assert "corrupt" not in status.stderr and "Traceback" not in status.stderr, status.stderr
    if not output.exists():                    # the kill landed before the file was complete
        assert "creation was interrupted" in one_line(status)
    result = hpcves("campaign", path, "--resume", "--quiet", "--io", io, n=2)
    assert result.returncode == 0, result.stderr
    assert not partial.exists()
    assert_same_results(output, reference_of(path, tmp_path))


@needs_mpi
def test_a_kill_at_an_exact_moment_of_creation_then_resume(tmp_path):
    """The 15th of the block's 21 arrays grown (by rank 0, which lays the file out alone in every mode):
    deterministic."""
    path, output = write_study(tmp_path / "job", t_end=0.002, shear=MANY, psi="[0.3, 0.4, 0.5]")
    from jobs import mpi_env

    killed = hpcves("campaign", path, "--quiet", n=2, env=mpi_env(HPCVES_FAULT="block-grown:15@0"))
    assert killed.returncode != 0
    assert not output.exists() and output.with_name(output.name + ".partial").exists()
    status = hpcves("status", output)
    assert "creation was interrupted" in one_line(status) and status.returncode == 3     # resubmit
    result = hpcves("campaign", path, "--resume", "--quiet", n=2)
    assert result.returncode == 0, result.stderr
    assert_same_results(output, reference_of(path, tmp_path))


@needs_mpi
def test_status_says_a_file_is_being_created(tmp_path):
    path, output = write_study(tmp_path / "job", t_end=0.002, shear=MANY, psi="[0.3, 0.4, 0.5]")
    partial = output.with_name(output.name + ".partial")
    job = start_job(2, "campaign", path, "--quiet")
    frozen = freeze_when(job, lambda: partial.exists() and not output.exists(), "the file is being created")
    try:
        status = hpcves("status", output)
    finally:
        thaw(frozen)
    assert status.returncode == 3, status.stderr                    # work left: a batch script resubmits
    assert "being created by a campaign (pid" in status.stdout
    job.communicate()
    assert job.returncode == 0


# ---------------------------------------------------------------------- 2. one writer, whatever the path
@needs_mpi
def test_a_second_campaign_is_refused_through_every_other_name_of_the_file(tmp_path):
    a, b = tmp_path / "A", tmp_path / "B"
    # frozen once two cases run: cases of t_end = 5 (~0.5 s each on the compiled step) leave time to see it
    path, output = write_study(a, t_end=5.0, checkpoint=0.1)
    job = start_job(2, "campaign", path, "--quiet")
    frozen = freeze_when(job, lambda: len(running_cases(output)) == 2, "two cases run")
    try:
        b.mkdir()
        (b / "alias.h5").symlink_to(output)
        os.link(output, b / "hard.h5")
        for other in (b / "alias.h5", a / ".." / "A" / output.name, b / "hard.h5"):
            result = hpcves("campaign", path, "--resume", "--out", other)
            line = one_line(result)
            assert result.returncode == 2
            assert ("is writing this file" in line) or ("hard links" in line and other.name == "hard.h5"), line
        os.unlink(b / "hard.h5")
    finally:
        kill_job(job) if frozen else None
    assert set(case_statuses(output).values()) <= {RUNNING, FINISHED, 0}
    result = hpcves("campaign", path, "--resume", "--quiet", "--out", b / "alias.h5")   # now it may
    assert result.returncode == 0, result.stderr
    assert (b / "alias.h5").is_symlink()                                  # the file was changed, not the link
    assert_same_results(output, reference_of(path, tmp_path))


def test_run_overwrite_refuses_a_file_another_run_is_writing(tmp_path):
    import sys

    case = tmp_path / "case.toml"
    case.write_text("[numerics]\nN = 32\n[run]\nmax_spectral_tail = 1.0\nt_end = 100.0\ncheckpoint_interval = 1.0\n")
    out = tmp_path / "x.h5"
    job = subprocess.Popen([sys.executable, "-m", "hpcves.cli", "run", str(case), "--out", str(out), "--quiet"],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_until(lambda: out.exists(), "the first run's file exists")
        result = hpcves("run", case, "--out", out, "--overwrite")
        line = one_line(result)
        assert result.returncode == 2 and "is writing this file" in line and "(hpcves run)" in line, line
        assert job.poll() is None
    finally:
        job.kill()
        job.wait()


# ---------------------------------------------------------------------- 10. ranks that outlive mpirun
@needs_mpi
def test_a_rank_that_outlives_rank_0_still_holds_the_lock(tmp_path):
    """``kill -9 -PGID`` of mpirun does not reach the ranks (each has a process group of its own), which
    then run on for about a second. The same state, made deterministic: mpirun and rank 1 frozen,
    rank 0 killed. A resume is refused while rank 1 lives, and works once it is gone."""
    from jobs import alive, job_pids

    # cases long enough (~0.5 s each on the compiled step) that two run checkpointed for a while
    path, output = write_study(tmp_path / "job", t_end=5.0, checkpoint=0.1)
    job = start_job(2, "campaign", path, "--quiet", "--io", "mpio")
    ranks = freeze_when(job, lambda: len(running_cases(output, checkpointed=True)) == 2, "two cases checkpoint")
    os.kill(job.pid, signal.SIGSTOP)                       # mpirun must not notice rank 0's death yet
    by_rank = {}
    for pid in ranks:
        with open(f"/proc/{pid}/environ", "rb") as f:
            env = dict(item.split(b"=", 1) for item in f.read().split(b"\0") if b"=" in item)
        by_rank[int(env[b"OMPI_COMM_WORLD_RANK"])] = pid
    os.kill(by_rank[0], signal.SIGKILL)
    wait_until(lambda: not alive(by_rank[0]), "rank 0 is gone")
    try:
        result = hpcves("campaign", path, "--resume", "--quiet")
        line = one_line(result)
        assert result.returncode == 2 and "rank 1 of the campaign started by pid" in line, line
        assert "still running" in line
    finally:
        pids = job_pids(job.pid) | {job.pid}
        for pid in pids:
            os.kill(pid, signal.SIGKILL)
        job.communicate()
        wait_until(lambda: not any(alive(p) for p in pids), "the job is gone")
    result = hpcves("campaign", path, "--resume", "--quiet", n=2)
    assert result.returncode == 0, result.stderr
    assert_same_results(output, reference_of(path, tmp_path))


# ---------------------------------------------------------------------- 3. full disks
@pytest.fixture
def small_disk(tmp_path):
    """``disk(megabytes)``: a directory on a tmpfs of that size (unmounted afterwards); skips where
    this machine does not allow mounting one (it needs root or CAP_SYS_ADMIN)."""
    mounted = []

    def disk(megabytes):
        where = tmp_path / f"disk{len(mounted)}"
        where.mkdir()
        done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={int(megabytes * 1024)}k", "tmpfs", str(where)],
                              capture_output=True, text=True)
        if done.returncode != 0:
            pytest.skip(f"cannot mount a small tmpfs here ({done.stderr.strip() or done.returncode})")
        mounted.append(where)
        return where

    yield disk
    for where in mounted:
        subprocess.run(["umount", "-l", str(where)], capture_output=True)


def fill(directory, leave_bytes):
    """Fill the file system of ``directory`` up to ``leave_bytes`` free: the filler file's path."""
    import shutil

    filler = directory / "filler"
    with open(filler, "wb") as f:
        free = shutil.disk_usage(directory).free - leave_bytes
        while free > 0:
            chunk = min(free, 1 << 20)
            f.write(b"\0" * chunk)
            free -= chunk
    return filler


def test_a_campaign_the_disk_has_no_room_for_is_refused_before_any_work(tmp_path, small_disk):
    disk = small_disk(2)
    path, output = write_study(tmp_path / "job", t_end=10.0, output=disk / "out.h5")      # about 3 MB
    result = hpcves("campaign", path)
    line = one_line(result)
    assert result.returncode == 2 and "needs" in line and "free" in line, line
    assert os.listdir(disk) == ["out.h5.lock"]            # no file, no .partial


def test_a_disk_that_fills_up_during_creation_leaves_no_file(tmp_path, small_disk, monkeypatch):
    """Another process fills the disk after the space was checked: creation fails cleanly."""
    disk = small_disk(2)
    path, output = write_study(tmp_path / "job", t_end=10.0, output=disk / "out.h5")
    from hpcves.files import atomic

    for module in (driver, atomic):           # the checks pass; then the disk is full
        monkeypatch.setattr(module, "require_space", lambda *args: None)
    with pytest.raises(StorageError, match="cannot create it .*nothing was written"):
        run_campaign(study_from_toml(path.read_text()), output)
    assert sorted(os.listdir(disk)) == ["out.h5.lock"]


def test_analyze_on_a_full_disk_leaves_the_file_as_it_was(tmp_path, small_disk):
    path, output = write_study(tmp_path / "job", t_end=0.1)
    assert run_campaign(study_from_toml(path.read_text()), output).exit_status == 0
    disk = small_disk(8)
    on_disk = disk / "camp.h5"
    on_disk.write_bytes(output.read_bytes())
    before = digest(on_disk)
    filler = fill(disk, 8 * 1024)
    # tables and figures elsewhere: they are written, the results are not stored in the file
    result = hpcves("analyze", on_disk, "--out", tmp_path / "tables", "--no-case-figures")
    assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr
    assert "results not written into the file" in result.stderr and "free" in result.stderr
    assert digest(on_disk) == before and not (disk / "camp.h5.partial").exists()
    # tables and figures on the full disk: one line, the file untouched
    result = hpcves("analyze", on_disk, "--no-case-figures")
    line = error_line(result)
    assert result.returncode == 2 and "No space left on device" in line and "camp.h5 is unchanged" in line, line
    assert digest(on_disk) == before
    # space freed: the results go in
    filler.unlink()
    result = hpcves("analyze", on_disk, "--out", tmp_path / "tables", "--no-case-figures")
    assert result.returncode == 0 and "results stored in" in result.stdout, result.stderr
    with h5py.File(on_disk, "r") as f:
        assert len(f["analysis/regime"]) == 4


def test_a_write_refused_while_cases_run_stops_the_campaign_and_loses_nothing(tmp_path, monkeypatch):
    """A full disk of a copy-on-write file system (btrfs, ZFS) can refuse even writes into place.
    The case is not failed: the campaign stops, every case keeps its last valid checkpoint."""
    import errno

    path, output = write_study(tmp_path / "job", t_end=0.1, checkpoint=0.02)
    study = study_from_toml(path.read_text())
    real = CaseStore._put
    writes = []

    def refuse_one(self, path, values, start=None):       # the store's write, as a full disk makes it fail
        if path.startswith("checkpoint/") and path.endswith("/scalars"):
            writes.append(path)
            if len(writes) == 5:             # the 5th checkpoint, its slot marked invalid, its arrays already in
                raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, path, values, start)

    monkeypatch.setattr(CaseStore, "_put", refuse_one)
    summary = run_campaign(study, output)
    assert summary.exit_status == 2 and "No space left on device" in summary.not_written
    assert summary.failed == () and summary.counts["failed"] == 0
    assert summary.counts["running"] == 1                # the case whose write failed: as after a kill
    monkeypatch.setattr(CaseStore, "_put", real)
    again = run_campaign(study, output, resume=True)
    assert again.exit_status == 0
    assert_same_results(output, reference_of(path, tmp_path))


# ---------------------------------------------------------------------- 4. absurd sizes, before any work
@pytest.mark.parametrize("numerics, run, words", [
    ("dt = 1e-3", "t_end = 1e9", ["1e+12 time steps", "surely a mistake"]),
    ("dt = 1e-15", "t_end = 1.0", ["1e+15 time steps", "surely a mistake"]),
])
def test_absurd_run_lengths_are_refused_with_the_numbers(tmp_path, numerics, run, words):
    case = tmp_path / "case.toml"
    case.write_text(f"[numerics]\nN = 32\n{numerics}\n[run]\nmax_spectral_tail = 1.0\n{run}\n")
    result = hpcves("run", case, "--out", tmp_path / "out.h5")
    line = one_line(result)
    assert result.returncode == 2 and all(w in line for w in words), line
    assert not (tmp_path / "out.h5").exists()


def test_a_study_no_disk_can_hold_is_refused_with_the_numbers(tmp_path):
    """10^8 steps a case (not absurd by itself), a sample every step: ~20 GB a case, ~20 TB for 1000."""
    from hpcves.run.diagnostics import SERIES

    path, output = write_study(tmp_path / "job", t_end=1e5, shear="{ linspace = [10, 400, 500] }",
                               psi="[0.3, 0.5]")
    path.write_text(path.read_text().replace("sample_interval = 0.005", "sample_interval = 1e-3"))
    result = hpcves("campaign", path)
    line = one_line(result)
    assert result.returncode == 2 and " TB, but only " in line, line
    series = 1000 * 1e8 * (len(SERIES) + 1) * 8 / 1e12          # TB of the time series alone
    needs = float(line.split("needs ")[1].split(" TB")[0])
    assert series <= needs < 1.3 * series, (needs, series)
    assert not output.exists()


# ---------------------------------------------------------------------- 5. one line, never a traceback
def test_outputs_that_cannot_be_files_get_one_line(tmp_path):
    path, output = write_study(tmp_path / "job", t_end=0.01)
    case = tmp_path / "case.toml"
    case.write_text("[numerics]\nN = 32\n[run]\nmax_spectral_tail = 1.0\nt_end = 0.01\n")
    (tmp_path / "afile").write_text("x")
    (tmp_path / "adir").mkdir()
    for args, words in (
            (["campaign", path, "--out", tmp_path / "afile" / "x.h5"], "is not a directory"),
            (["campaign", path, "--out", tmp_path / "adir", "--overwrite"], "is a directory"),
            (["campaign", path, "--out", tmp_path / "adir", "--resume"], "is a directory"),
            (["run", case, "--out", tmp_path / "afile" / "x.h5"], "is not a directory"),
            (["run", case, "--out", tmp_path / "adir", "--overwrite"], "is a directory"),
            (["run", "--resume", tmp_path / "adir"], "is a directory"),
            (["status", tmp_path / "adir"], "is a directory"),
            (["analyze", tmp_path / "adir"], "is a directory")):
        result = hpcves(*args)
        line = one_line(result)
        assert result.returncode == 2 and words in line, (args, line)


def test_a_read_only_directory_gets_one_line(tmp_path, small_disk):
    disk = small_disk(4)
    subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True)
    path, output = write_study(tmp_path / "job", t_end=0.01, output=disk / "x.h5")
    case = tmp_path / "case.toml"
    case.write_text("[numerics]\nN = 32\n[run]\nmax_spectral_tail = 1.0\nt_end = 0.01\n")
    for args in (["campaign", path], ["run", case, "--out", disk / "y.h5"]):
        result = hpcves(*args)
        line = one_line(result)
        assert result.returncode == 2 and "Read-only file system" in line, (args, line)


def test_a_toml_file_that_is_not_utf8_gets_one_line(tmp_path):
    path, _ = write_study(tmp_path / "job", t_end=0.01)
    path.write_bytes(path.read_bytes().replace(b'name = "faults"', b'name = "f\xe4ults"'))
    for args in (["campaign", path], ["run", path, "--out", tmp_path / "o.h5"]):
        result = hpcves(*args)
        line = one_line(result)
        assert result.returncode == 2 and "not UTF-8" in line and "0xe4" in line, line


def flip_header(path, dataset):
    """Flip the version byte of ``dataset``'s object header: HDF5 can no longer open that object."""
    with h5py.File(path, "r") as f:
        address = h5py.h5o.get_info(f[dataset].id).addr
    with open(path, "r+b") as f:
        f.seek(address)
        byte = f.read(1)
        f.seek(address)
        f.write(bytes([byte[0] ^ 0x40]))


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A small finished campaign (4 cases), the study file and the file."""
    directory = tmp_path_factory.mktemp("finished")
    path, output = write_study(directory, t_end=0.05, checkpoint=0.02)
    assert run_campaign(study_from_toml(path.read_text()), output).exit_status == 0
    return path, output


@pytest.fixture(scope="module")
def finished_v1(tmp_path_factory):
    """``finished`` in the older layout (campaign format 1: a group per case)."""
    directory = tmp_path_factory.mktemp("finished_v1")
    path, output = write_study(directory, t_end=0.05, checkpoint=0.02)
    with writing_format(1):
        assert run_campaign(study_from_toml(path.read_text()), output).exit_status == 0
    return path, output


def damaged_copy(finished, tmp_path, name="damaged.h5"):
    path, output = finished
    copy = tmp_path / name
    copy.write_bytes(output.read_bytes())
    return path, copy


@pytest.mark.parametrize("version", [1, 3])
def test_a_bit_flipped_campaign_file_gets_one_line_everywhere(finished, finished_v1, tmp_path, version):
    """Format 1: the damaged case is named, the others read; format 3, where every case of a block shares
    the dataset: every case of the block is damaged, each named."""
    path, copy = damaged_copy(finished if version == 3 else finished_v1, tmp_path)
    flip_header(copy, "cases/0002/timeseries/theta" if version == 1 else "blocks/0/timeseries/series")
    assert hpcves("status", copy).returncode == 0          # status reads the status and progress only ...
    status = hpcves("status", "--check", copy)            # ... unless asked to check everything
    assert status.returncode == 2 and "0002" in one_line(status) and "damaged" in one_line(status)
    assert "0003" in status.stdout                     # the other cases are still shown
    flip_header(copy, "cases/0001/progress" if version == 1 else "blocks/0/progress")
    status = hpcves("status", copy)
    assert status.returncode == 2 and "0001" in one_line(status), status.stderr
    analyzed = hpcves("analyze", copy, "--out", tmp_path / "a", "--no-case-figures")
    assert analyzed.returncode == 2 and "0002" in error_line(analyzed), analyzed.stderr
    if version == 1:
        assert (tmp_path / "a" / "regimes.csv").exists()   # the others are analysed
    resumed = hpcves("campaign", path, "--resume", "--out", copy)
    assert resumed.returncode == 2 and f"case 000{2 if version == 1 else 0}" in one_line(resumed), resumed.stderr


# ---------------------------------------------------------------------- 7. what --resume refuses
def damage_missing_series(f):
    del f["cases/0001/timeseries/theta"]


def damage_checkpoint_shape(f):
    del f["cases/0002/checkpoint/slot0/theta"]
    f["cases/0002/checkpoint/slot0"].create_dataset("theta", data=np.zeros(33))


def damage_status(f):
    case_view(f, "0003")["status"] = 77


def damage_length(f):
    case_view(f, "0000")["timeseries/length"] = 10_000


def damage_block_series(f):
    del f["blocks/0/timeseries/series"]


def damage_block_checkpoint_shape(f):
    del f["blocks/0/checkpoint/slot0/arrays"]
    f["blocks/0/checkpoint/slot0"].create_dataset("arrays", data=np.zeros((4, 8, 33)))


@pytest.mark.parametrize("version, damage, case, words", [
    (1, damage_missing_series, "0001", "timeseries/theta is missing"),
    (1, damage_checkpoint_shape, "0002", "checkpoint/slot0/theta has shape (33,)"),
    (1, damage_status, "0003", "status 77 is not a status"),
    (3, damage_status, "0003", "status 77 is not a status"),
    (3, damage_length, "0000", "timeseries/length = 10000 lies outside"),
    (3, damage_block_series, "0000", "timeseries/series is missing"),
    (3, damage_block_checkpoint_shape, "0000", "checkpoint/slot0/arrays has shape (8, 33)"),
])
def test_resume_refuses_a_damaged_case_naming_it(finished, finished_v1, tmp_path, version, damage, case, words):
    path, copy = damaged_copy(finished if version == 3 else finished_v1, tmp_path)
    with h5py.File(copy, "r+") as f:
        damage(f)
    before = digest(copy)
    result = hpcves("campaign", path, "--resume", "--out", copy)
    line = one_line(result)
    assert result.returncode == 2 and f"case {case}: {words}" in line, line
    assert digest(copy) == before


def test_run_resume_refuses_a_damaged_case_file(tmp_path):
    case = tmp_path / "case.toml"
    case.write_text("[numerics]\nN = 32\n[run]\nmax_spectral_tail = 1.0\nt_end = 0.02\ncheckpoint_interval = 0.01\n")
    out = tmp_path / "one.h5"
    assert hpcves("run", case, "--out", out, "--quiet").returncode == 0
    with h5py.File(out, "r+") as f:
        f["status"][()] = 1
        f["timeseries/length"][()] = 10_000
    result = hpcves("run", "--resume", out)
    assert result.returncode == 2 and "timeseries/length = 10000" in one_line(result)


# ---------------------------------------------------------------------- 8. inputs that must be refused
@pytest.mark.parametrize("sweep, words", [
    ("shear_rate = [40, 40]\npsi_bar = 0.3", "sweep.shear_rate: 40 (2 times)"),
    ("shear_rate = [40, 40.0000000000001]\npsi_bar = 0.3", "sweep.shear_rate: 40 (2 times)"),
    ("shear_rate = { logspace = [40, 40, 3] }\npsi_bar = 0.3", "40 (3 times)"),
    ("shear_rate = 40\npsi_bar = { linspace = [0.3, 0.5, 1000000000] }", "num = 1000000000 must lie in"),
])
def test_sweeps_that_repeat_a_value_or_are_absurd_are_refused(sweep, words):
    from hpcves.model.params import ConfigError

    text = tiny_study("x.h5", "faults", checkpoint=0.02).split("[sweep]")[0] + "[sweep]\n" + sweep
    with pytest.raises(ConfigError, match=words.replace("(", r"\(").replace(")", r"\)")):
        study_from_toml(text)


def test_the_case_limit_is_checked_before_any_case_is_built(monkeypatch):
    from hpcves.campaign import study as study_module
    from hpcves.model.params import ConfigError

    def never(*args, **kwargs):
        raise AssertionError("a case was built")

    monkeypatch.setattr(study_module.Study, "make_case", never)
    text = (tiny_study("x.h5", "faults", checkpoint=0.02).split("[sweep]")[0]
            + "[sweep]\nshear_rate = { linspace = [1, 400, 1000] }\npsi_bar = { linspace = [0.25, 0.75, 1000] }\n")
    with pytest.raises(ConfigError, match="has 1000000 cases; more than 100000"):
        study_from_toml(text)


# ---------------------------------------------------------------------- 6. analysis results that went stale
def test_analyze_does_not_store_results_of_a_file_that_changed_meanwhile(tmp_path, monkeypatch):
    from hpcves.reports import analyze as analysis

    path, output = write_study(tmp_path / "job", t_end=0.1, checkpoint=0.02)
    study = study_from_toml(path.read_text())
    from hpcves.run import runner

    real_run = runner.run

    def stop_early(store, flush, **kwargs):              # every case interrupted after 30 steps
        return real_run(store, flush, **{**kwargs, "max_steps": 30})

    monkeypatch.setattr(runner, "run", stop_early)
    run_campaign(study, output)
    monkeypatch.setattr(runner, "run", real_run)
    real_classify = analysis.analyze_source

    def classify_while_a_resume_finishes_it(source, *args, **kwargs):
        rows = real_classify(source, *args, **kwargs)
        assert run_campaign(study, output, resume=True).exit_status == 0
        return rows

    monkeypatch.setattr(analysis, "analyze_source", classify_while_a_resume_finishes_it)
    report = analysis.analyze(output, tmp_path / "a", case_figures=False)
    assert not report.wrote_back
    assert "changed while it was analysed" in report.note and "now finished" in report.note
    with h5py.File(output, "r") as f:
        assert "analysis" not in f
    monkeypatch.setattr(analysis, "analyze_source", real_classify)
    again = analysis.analyze(output, tmp_path / "a", case_figures=False)
    assert again.wrote_back and {r["status"] for r in again.rows} == {"finished"}


# ---------------------------------------------------------------------- the fault-injection subset
SMALL = 8                                  # the harness study with 3 x 8 cases: enough for every kill point


@pytest.fixture(scope="module")
def harness_references(tmp_path_factory):
    """The harness study run uninterrupted, per time stepping (made when first asked for)."""
    import faults as harness

    made = {}

    def get(stepping: str = "fixed"):
        if stepping not in made:
            made[stepping] = harness.reference(tmp_path_factory.mktemp(f"harness-{stepping}"), SMALL, stepping)
        return made[stepping]
    return get


@pytest.fixture(scope="module")
def harness_reference(harness_references):
    return harness_references("fixed")


# Four moments in `make test`, one of each kind; the other four (same kinds, other rank, mode or
# stepping) carry the `faults` marker and run in `make faults`, to keep `make test` short. A worker's
# moment is its first finished case: ranks ask for cases as they come up, and on the compiled step the
# 24 cases take ~2 s, so rank 2 finished a second one in only 4 of 8 jobs (its first in 8 of 8).
more = pytest.mark.faults


@needs_mpi
@pytest.mark.parametrize("fault, n, io, stepping", [
    ("publish", 3, "relay", "fixed"),                # the file complete under .partial, killed before the rename
    pytest.param("block-grown:20@0", 2, "relay", "fixed", marks=more),     # rank 0 laying the file out alone
    ("checkpoint:7@1", 3, "mpio", "fixed"),          # rank 1 inside a checkpoint write (two points in each)
    pytest.param("checkpoint:12@0", 3, "relay", "fixed", marks=more),      # rank 0 applying another rank's checkpoint
    pytest.param("finished:3@0", 2, "mpio", "fixed", marks=more),          # rank 0 just after a case finished
    ("finished:1@2", 3, "relay", "fixed"),           # a worker just after its first case finished
    pytest.param("checkpoint:7@1", 3, "mpio", "adaptive", marks=more),     # with the step controller's state
    ("checkpoint:12@0", 3, "relay", "adaptive"),     # rank 0 applying a checkpoint, adaptive stepping
])
def test_a_kill_at_an_exact_moment_resumes_bitwise(tmp_path, harness_references, fault, n, io, stepping):
    import faults as harness
    from jobs import mpi_env

    path, output = harness.write_study(tmp_path / "job", SMALL, stepping)
    killed = hpcves(*harness.campaign_args(path, io), n=n, env=mpi_env(HPCVES_FAULT=fault))
    assert killed.returncode != 0, "the fault point was never reached"
    result = hpcves(*harness.campaign_args(path, io, resume=True), n=n)
    assert result.returncode == 0, result.stderr
    assert_same_results(output, harness_references(stepping))


def test_a_serial_campaign_killed_inside_a_checkpoint_resumes_bitwise(tmp_path, harness_reference):
    import faults as harness
    from jobs import mpi_env

    path, output = harness.write_study(tmp_path / "job", SMALL)
    killed = hpcves("campaign", path, "--quiet", env=mpi_env(HPCVES_FAULT="checkpoint:25"))
    assert killed.returncode == -signal.SIGKILL
    assert hpcves("campaign", path, "--quiet", "--resume").returncode == 0
    assert_same_results(output, harness_reference)


def test_a_run_killed_inside_a_checkpoint_resumes_bitwise(tmp_path):
    from jobs import mpi_env

    case = tmp_path / "case.toml"
    case.write_text("[physics]\nshear_rate = 80.0\n[numerics]\nN = 32\n[run]\nmax_spectral_tail = 1.0\nt_end = 0.2\n"
                    "sample_interval = 0.005\nsnapshot_interval = 0.05\ncheckpoint_interval = 0.02\n")
    assert hpcves("run", case, "--out", tmp_path / "a.h5", "--quiet").returncode == 0
    killed = hpcves("run", case, "--out", tmp_path / "b.h5", "--quiet", env=mpi_env(HPCVES_FAULT="checkpoint:9"))
    assert killed.returncode == -signal.SIGKILL
    with h5py.File(tmp_path / "b.h5", "r") as f:                  # killed between invalidating and validating
        assert sorted(int(f[f"checkpoint/{s}/meta"][0]) for s in ("slot0", "slot1")) == [0, 1]
    assert hpcves("run", "--resume", tmp_path / "b.h5", "--quiet").returncode == 0
    with h5py.File(tmp_path / "a.h5", "r") as a, h5py.File(tmp_path / "b.h5", "r") as b:
        for group in ("timeseries", "snapshots"):
            for name in a[group]:
                assert np.array_equal(a[group][name][()], b[group][name][()], equal_nan=True), (group, name)


def test_analyze_killed_before_storing_its_results_leaves_the_file_as_it_was(tmp_path, finished):
    from jobs import mpi_env

    _, output = finished
    copy = tmp_path / "copy.h5"
    copy.write_bytes(output.read_bytes())
    before = digest(copy)
    killed = hpcves("analyze", copy, "--out", tmp_path / "a", "--no-case-figures",
                    env=mpi_env(HPCVES_FAULT="analysis-stored"))
    assert killed.returncode == -signal.SIGKILL
    assert digest(copy) == before and (tmp_path / "copy.h5.partial").exists()
    result = hpcves("analyze", copy, "--out", tmp_path / "a", "--no-case-figures")
    assert result.returncode == 0 and "results stored" in result.stdout, result.stderr
    assert not (tmp_path / "copy.h5.partial").exists()


@needs_mpi
@pytest.mark.faults           # make faults runs it, then the 40 random kills it stands for (24 s: out of make test)
def test_two_random_kills_of_the_fault_injection_harness(tmp_path, harness_reference):
    """What `make faults` does 40 times: here once during creation, once at the end (mpirun's group
    only: the resume starts at once and must wait for the ranks), at random moments of those phases."""
    import random

    import faults as harness

    rng = random.Random(7)
    for planned, mode in (("creation", "job"), ("end", "group")):
        for attempt in range(20):      # until the kill hits a live job (the job may end before it comes)
            # the moments are measured again before each try: the load of a shared machine changes
            # how long a job takes, and a kill aimed at the end of a slower job comes too late
            timeline = harness.measure(tmp_path / f"timeline-{planned}-{attempt}", 2, "mpio", SMALL)
            trial = harness.trial(tmp_path / "trial", 2, "mpio", timeline, rng, harness_reference,
                                  planned=planned, mode=mode, again=False, points=SMALL)
            assert trial.identical, trial.differences[:5]
            if trial.landed:
                break
        assert trial.landed, f"no kill aimed at {planned} found the job alive"


# ---------------------------------------------------------------------- 9. readers of a live file
@needs_mpi
def test_readers_of_a_live_file_always_find_it_whole(tmp_path):
    """Read every dataset of every case again and again while a search campaign runs its stages
    (each one replaces the file with a copy holding the new cases): never an error, and the reads
    span several stages."""
    from hpcves.campaign.file import read_table
    from test_search_campaign import write_search

    path, output = write_search(tmp_path, checkpoint=0.05)
    job = start_job(2, "campaign", path, "--quiet")
    seen, reads = set(), 0
    while job.poll() is None:
        if not output.exists():
            time.sleep(0.01)
            continue
        table = read_table(output, check=True)                  # what hpcves status --check does
        assert all(row["status"] != "damaged" for row in table.rows), table.rows
        with h5py.File(output, "r", locking=False) as f:        # and every byte a reader could want
            seen.add(int(f.attrs["n_cases"]))
            f.visititems(lambda name, obj: obj[()] if isinstance(obj, h5py.Dataset) else None)
        reads += 1
    out, err = job.communicate()
    assert job.returncode == 0, err
    assert len(seen) >= 3 and reads >= 10, (seen, reads)        # stages of 4, then more cases each

def outside_raw_data(path):
    """The bytes of an HDF5 file that are not raw data of a dataset: its metadata, as a reader parses it."""
    ranges = []
    with h5py.File(path, "r") as f:
        def visit(name, obj):
            if isinstance(obj, h5py.Dataset) and obj.chunks is not None:           # blocks (formats 2, 3)
                for i in range(obj.id.get_num_chunks()):
                    chunk = obj.id.get_chunk_info(i)
                    ranges.append((chunk.byte_offset, chunk.byte_offset + chunk.size))
            elif isinstance(obj, h5py.Dataset) and obj.id.get_offset() is not None:
                ranges.append((obj.id.get_offset(), obj.id.get_offset() + obj.id.get_storage_size()))
        f.visititems(visit)
    data = bytearray(path.read_bytes())
    for start, stop in ranges:
        data[start:stop] = bytes(stop - start)
    return bytes(data)


@needs_mpi
def test_running_cases_change_no_byte_of_the_metadata(tmp_path):
    """Why a reader of a live file always finds it whole: after creation, the cases (here under mpio,
    killed inside a checkpoint write) write raw data into preallocated space and nothing else."""
    import shutil

    from jobs import mpi_env

    path, output = write_study(tmp_path / "job", t_end=0.1, checkpoint=0.01)
    partial = output.with_name(output.name + ".partial")
    made = hpcves("campaign", path, "--quiet", n=2, env=mpi_env(HPCVES_FAULT="publish"))
    assert made.returncode != 0 and partial.exists() and not output.exists()     # complete, not renamed
    created = tmp_path / "created.h5"
    shutil.copy(partial, created)
    os.replace(partial, output)
    ran = hpcves("campaign", path, "--resume", "--quiet", n=2, env=mpi_env(HPCVES_FAULT="checkpoint:9@1"))
    assert ran.returncode != 0
    assert RUNNING in case_statuses(output).values()                  # rank 1's case, killed mid-checkpoint
    assert outside_raw_data(output) == outside_raw_data(created)
    assert output.read_bytes() != created.read_bytes()                            # the cases did write


def test_a_search_stage_the_disk_has_no_room_for_stops_the_campaign_and_loses_nothing(tmp_path, monkeypatch):
    """The second stage's copy is refused (a full disk): exit status 2, the file as the first stage
    left it, and once there is room the resume reaches the uninterrupted search's file bit for bit."""
    from test_search_campaign import write_search

    path, output = write_search(tmp_path)
    study = study_from_toml(path.read_text())
    real_copy = structure.copy_for_change
    copies = []

    def refuse_the_second(path, extra, what):
        copies.append(what)
        if len(copies) == 2:
            raise StorageError(f"{path}: {what} needs 1 MB, but only 8 kB is free there")
        return real_copy(path, extra, what)

    monkeypatch.setattr(structure, "copy_for_change", refuse_the_second)
    summary = run_campaign(study, output)
    assert summary.exit_status == 2 and "adding stage 2's" in summary.not_written
    with h5py.File(output, "r") as f:
        assert f.attrs["n_cases"] == f["index/case_id"].shape[0] == 4 and not os.path.exists(f"{output}.partial")
    assert set(case_statuses(output).values()) == {FINISHED}
    monkeypatch.setattr(structure, "copy_for_change", real_copy)
    assert run_campaign(study, output, resume=True).exit_status == 0
    reference = tmp_path / "reference" / "search.h5"
    reference.parent.mkdir()
    assert run_campaign(study, reference).exit_status == 0
    assert_same_results(output, reference)
