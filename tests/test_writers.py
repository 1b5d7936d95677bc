"""One writer at a time whatever the command, and the tool's side files never taken for outputs (issue 64).

Every command that writes or replaces an hpcves file -- ``hpcves run`` (new, --overwrite, --resume),
``hpcves campaign`` (new, --overwrite, --resume), ``hpcves analyze`` -- takes the file's one write lock
(files/lock.py) first, so none of them replaces or writes a file another one is writing. And a name
hpcves gives the files it keeps beside a file (``<name>.lock``, ``<name>.partial``, ``<name>.jobs``,
a figure's ``<stem>.partial.<ext>``) is refused as an output: a later command on ``<name>`` truncated
``a.h5.lock`` to 0 bytes (taking it for its lock) and deleted ``b.h5.partial`` (as debris).
"""
import os
import signal
import subprocess
import sys
import time

import pytest
from click.testing import CliRunner

from conftest import write_tiny_study
from hpcves.cli import main
from hpcves.config import case_from_toml
from hpcves.files.lock import CampaignLock, writer
from hpcves.run.casefile import create_case_file, open_for_resume

CASE = ("[numerics]\nN = 32\ndt = 1e-3\n[run]\nmax_spectral_tail = 1.0\nt_end = 0.02\nsample_interval = 0.005\n"
        "snapshot_interval = 0.01\n")


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def refused(result) -> str:
    """The one line of a refusal (exit 2, no traceback)."""
    assert result.exit_code == 2, (result.exit_code, result.output)
    assert "Traceback" not in result.output, result.output
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, lines
    return lines[0]


@pytest.fixture
def case_file(tmp_path):
    path = tmp_path / "case.toml"
    path.write_text(CASE)
    return path


@pytest.mark.parametrize("suffix", [".lock", ".partial", ".jobs", ".idle_jobs", ".progress_seen", ".status.json"])
def test_an_output_named_like_a_side_file_is_refused_by_every_command_that_makes_one(tmp_path, case_file, suffix):
    """`campaign --out a.h5.lock` made an HDF5 file that a later `campaign --out a.h5` truncated to
    0 bytes as its lock; `--out b.h5.partial` was deleted as debris by a later command on b.h5."""
    study, _ = write_tiny_study(tmp_path / "s", t_end=0.01, shear="[40]", psi="[0.3]")
    out = tmp_path / f"a.h5{suffix}"
    for args in (("run", case_file, "--out", out), ("campaign", study, "--out", out),
                 ("campaign", study, "--out", out, "--resume")):
        line = refused(invoke(*args))
        assert f"'{suffix}' ends the names hpcves gives the files it keeps beside a.h5" in line, line
        assert "choose another name" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["case.toml", "s"]


def test_a_link_to_a_side_file_name_is_refused_too(tmp_path, case_file):
    (tmp_path / "c.h5").symlink_to(tmp_path / "x.h5.partial")
    line = refused(invoke("run", case_file, "--out", tmp_path / "c.h5"))
    assert "'.partial' ends the names" in line, line
    assert not (tmp_path / "x.h5.partial").exists()


def test_figure_and_movie_outputs_named_like_their_partials_are_refused(tmp_path):
    for command in ("shapes", "animate"):
        args = [command, tmp_path / "none.h5", "--out", tmp_path / "f.partial.gif"]
        if command == "shapes":
            args += ["--case", "0000"]
        line = refused(invoke(*args))
        assert "while it draws it" in line, line
    assert list(tmp_path.iterdir()) == []


def test_a_foreign_file_under_a_lock_files_name_is_never_truncated(tmp_path, case_file):
    """Whatever made ``a.h5.lock`` (an older hpcves, a cp), a writer of a.h5 refuses to lock with it."""
    foreign = tmp_path / "a.h5.lock"
    foreign.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(100))
    before = foreign.read_bytes()
    study, _ = write_tiny_study(tmp_path / "s", t_end=0.01, shear="[40]", psi="[0.3]")
    for args in (("run", case_file, "--out", tmp_path / "a.h5"), ("campaign", study, "--out", tmp_path / "a.h5")):
        line = refused(invoke(*args))
        assert "holds 108 bytes of another file (not a lock note)" in line and "move it away" in line, line
    assert foreign.read_bytes() == before
    assert not (tmp_path / "a.h5").exists()


def test_a_run_holds_its_files_lock_and_other_writers_are_refused(tmp_path, case_file):
    """`hpcves campaign ... --overwrite` replaced a live `hpcves run`'s file (which went on writing into
    an unlinked file and exited 0); analyze would store results beside a run that advances."""
    path = tmp_path / "c.h5"
    opened = create_case_file(path, case_from_toml(CASE))
    try:
        assert "(hpcves run)" in (writer(path) or ""), writer(path)
        inode = path.stat().st_ino
        study, _ = write_tiny_study(tmp_path / "s", t_end=0.01, shear="[40]", psi="[0.3]")
        for args in (("campaign", study, "--out", path, "--overwrite"),
                     ("run", case_file, "--out", path, "--overwrite"),
                     ("run", "--resume", path)):
            line = refused(invoke(*args))
            assert "another hpcves process (a run, a campaign or analyze) is writing this file" in line, line
            assert "(hpcves run)" in line, line
        assert path.stat().st_ino == inode
        with pytest.raises(Exception, match="is writing this file"):
            open_for_resume(path)
    finally:
        opened.close()
    assert writer(path) is None                     # released with the file
    assert invoke("run", "--resume", path).exit_code == 0


def test_a_campaigns_lock_refuses_a_run_that_would_replace_its_file(tmp_path, case_file):
    """`hpcves run --out c.h5 --overwrite` replaced a live mpio campaign's file: the campaign's ranks
    kept writing into the unlinked file. (The campaign's claim is its lock, held by every rank.)"""
    study, path = write_tiny_study(tmp_path / "s", t_end=0.01, shear="[40]", psi="[0.3]")
    assert invoke("campaign", study).exit_code == 0
    before = path.read_bytes()
    lock = CampaignLock(path, "hpcves campaign").acquire()        # as a running campaign's rank 0 holds it
    try:
        for args in (("run", case_file, "--out", path, "--overwrite"), ("campaign", study, "--overwrite"),
                     ("campaign", study, "--resume")):
            line = refused(invoke(*args))
            assert "is writing this file" in line and "(hpcves campaign)" in line, line
    finally:
        lock.release()
    assert path.read_bytes() == before


def test_a_live_run_in_another_process_keeps_its_file(tmp_path, case_file):
    """The same across processes: a real `hpcves run` is running; replacing its file is refused, and
    the run ends with its own file whole."""
    long_case = tmp_path / "long.toml"
    long_case.write_text(CASE.replace("t_end = 0.02", "t_end = 50.0"))
    path = tmp_path / "live.h5"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    run = subprocess.Popen([sys.executable, "-m", "hpcves", "run", str(long_case), "--out", str(path), "--quiet"],
                           env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300                    # guards against a hang only
        while writer(path) is None or not path.exists():
            assert run.poll() is None, run.communicate()
            assert time.monotonic() < deadline
            time.sleep(0.05)
        inode = path.stat().st_ino
        study, _ = write_tiny_study(tmp_path / "s", t_end=0.01, shear="[40]", psi="[0.3]")
        line = refused(invoke("campaign", study, "--out", path, "--overwrite"))
        assert "is writing this file" in line and "(hpcves run)" in line, line
        line = refused(invoke("run", case_file, "--out", path, "--overwrite"))
        assert "is writing this file" in line, line
        assert path.stat().st_ino == inode
    finally:
        run.send_signal(signal.SIGTERM)                      # stops cleanly with a checkpoint
        out, err = run.communicate(timeout=300)
    assert run.returncode == 0, err
    assert "resume with: hpcves run --resume" in out, out
    assert writer(path) is None


@pytest.mark.parametrize("command", ["run", "campaign"])
def test_a_users_file_under_the_partial_name_is_kept_and_the_command_refused(tmp_path, case_file, command):
    """hpcves removes the ``.partial`` an interrupted change left (an HDF5 file, or the zeros of a
    reservation made before its first bytes); a file of the user's that bears the name is neither
    removed nor truncated: the command refuses, naming it."""
    study, _ = write_tiny_study(tmp_path / "s", t_end=0.01, shear="[40]", psi="[0.3]")
    out = tmp_path / "b.h5"
    notes = tmp_path / "b.h5.partial"
    notes.write_text("my notes on b.h5\n")
    args = ("run", case_file, "--out", out) if command == "run" else ("campaign", study, "--out", out)
    line = refused(invoke(*args))
    assert f"{notes}: there, but not a file hpcves left" in line and "move it away" in line, line
    assert notes.read_text() == "my notes on b.h5\n" and not out.exists()
    notes.unlink()
    notes.write_bytes(b"\0" * 4096)                      # a reservation cut short: hpcves's own debris
    result = invoke(*args)
    assert result.exit_code == 0, result.output
    assert out.exists() and not notes.exists()
