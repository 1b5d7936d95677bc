"""`hpcves run`: bad input, the HDF5 layout, resume, divergence, interruption."""
import re
import signal
import subprocess
import sys

import h5py
import numpy as np
import pytest

from hpcves.config import case_from_toml
from hpcves.run import runner
from hpcves.run.store import FAILED, FINISHED, INTERRUPTED, CaseStore
from jobs import SHORT, resume_in_process, run_in_process, same_case_files, wait_until

HPCVES = [sys.executable, "-m", "hpcves.cli"]


def hpcves(*args, **kwargs):
    return subprocess.run(HPCVES + [str(a) for a in args], capture_output=True, text=True, timeout=300,
                          **kwargs)


def write(tmp_path, text, name="case.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def assert_clean_error(result, *fragments):
    assert result.returncode == 2, (result.returncode, result.stdout, result.stderr)
    assert "Traceback" not in result.stderr
    lines = [line for line in result.stderr.strip().splitlines() if line.strip()]
    assert len(lines) == 1, result.stderr
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])


BAD_CASES = {
    "unknown key": ("[physics]\nshear = 3\n", ["unknown key", "shear"]),
    "unknown table": ("[physic]\nshear_rate = 3\n", ["unknown table", "[physic]"]),
    "wrong type": ("[numerics]\nN = 64.5\n", ["numerics.N", "integer"]),
    "string for number": ("[run]\nt_end = \"5\"\n", ["run.t_end", "number"]),
    "N odd": ("[numerics]\nN = 63\n", ["numerics.N = 63", "even"]),
    "N too small": ("[numerics]\nN = 8\n", ["numerics.N = 8", "too small"]),
    "psi_bar above 1": ("[physics]\npsi_bar = 1.2\n", ["physics.psi_bar = 1.2"]),
    "psi_bar below 0": ("[physics]\npsi_bar = -0.1\n", ["physics.psi_bar = -0.1"]),
    "negative excess length": ("[physics]\nexcess_length = -0.05\n", ["excess_length", "no ellipse"]),
    "dt zero": ("[numerics]\ndt = 0.0\n", ["numerics.dt = 0.0", "> 0"]),
    "dt negative": ("[numerics]\ndt = -1e-3\n", ["numerics.dt"]),
    "not TOML": ("[physics\nshear_rate = 1\n", ["not valid TOML"]),
    "bad choice": ("[physics]\npsi_init_coordinate = \"polar\"\n", ["psi_init_coordinate", "arclength"]),
}


@pytest.mark.parametrize("name", list(BAD_CASES))
def test_bad_case_files_get_one_clear_message(tmp_path, name):
    text, fragments = BAD_CASES[name]
    result = hpcves("run", write(tmp_path, text), "--out", tmp_path / "out.h5")
    assert_clean_error(result, *fragments)
    assert not (tmp_path / "out.h5").exists()


def test_missing_case_file(tmp_path):
    assert_clean_error(hpcves("run", tmp_path / "nope.toml", "--out", tmp_path / "o.h5"), "no such file")


def test_resume_needs_an_existing_hpcves_file(tmp_path):
    assert_clean_error(hpcves("run", "--resume", tmp_path / "missing.h5"), "no such file")
    not_hdf5 = tmp_path / "text.h5"
    not_hdf5.write_text("hello")
    assert_clean_error(hpcves("run", "--resume", not_hdf5), "not a readable HDF5 file")
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["data"] = np.arange(3)
    assert_clean_error(hpcves("run", "--resume", foreign), "not an hpcves case")


def test_resume_of_a_truncated_file(tmp_path):
    path = tmp_path / "case.h5"
    result = hpcves("run", write(tmp_path, SHORT.format(t_end=0.05, checkpoint=0.02)), "--out", path, "--quiet")
    assert result.returncode == 0, result.stderr
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    assert_clean_error(hpcves("run", "--resume", path), str(path))


def test_existing_output_is_not_overwritten(tmp_path):
    case = write(tmp_path, SHORT.format(t_end=0.01, checkpoint=0.01))
    out = tmp_path / "out.h5"
    out.write_bytes(b"precious")
    assert_clean_error(hpcves("run", case, "--out", out), "exists already")
    assert out.read_bytes() == b"precious"


def test_run_writes_the_documented_layout(tmp_path):
    out = tmp_path / "case.h5"
    result = hpcves("run", write(tmp_path, SHORT.format(t_end=0.2, checkpoint=0.1)), "--out", out, "--quiet")
    assert result.returncode == 0, result.stderr
    assert "finished at t = 0.2" in result.stdout
    with h5py.File(out, "r") as f:
        assert f.attrs["physics.shear_rate"] == 80.0 and f.attrs["numerics.N"] == 32
        assert "[physics]" in f.attrs["config"]
        n = f["timeseries/length"][()]
        assert n == 41                                               # t = 0, 0.005, ..., 0.2
        for name in ("t", "theta", "area_error", "length_error", "E_bending", "E_phase", "tension_min",
                     "tension_mean", "tension_max", "V_psi", "V_L"):
            assert np.all(np.isfinite(f["timeseries"][name][:n])), name
        assert f["timeseries/centroid"].shape[1] == 2
        assert np.allclose(f["timeseries/t"][:n], np.arange(n) * 0.005)
        assert f["snapshots/length"][()] == 5
        for name in ("x", "y", "psi", "tension", "curvature"):
            assert f["snapshots"][name].shape[1] == 32
        assert f["status"][()] == FINISHED
        assert {"slot0", "slot1"} <= set(f["checkpoint"])


compare_files = same_case_files


def test_resume_is_bitwise_identical_in_process(tmp_path):
    case = case_from_toml(SHORT.format(t_end=0.3, checkpoint=0.04))
    assert run_in_process(case, tmp_path / "a.h5").status == FINISHED
    assert run_in_process(case, tmp_path / "b.h5", max_steps=97).status == INTERRUPTED
    assert resume_in_process(tmp_path / "b.h5", stops=(55, None)).status == FINISHED
    compare_files(tmp_path / "a.h5", tmp_path / "b.h5")


def test_resume_after_sigkill_is_bitwise_identical(tmp_path):
    case = write(tmp_path, SHORT.format(t_end=8.0, checkpoint=0.1))
    assert hpcves("run", case, "--out", tmp_path / "a.h5", "--quiet").returncode == 0
    b = tmp_path / "b.h5"
    proc = subprocess.Popen(HPCVES + ["run", str(case), "--out", str(b), "--quiet"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    def checkpointed():                 # the writer holds the HDF5 lock: peek without it
        assert proc.poll() is None, "the run ended before it could be killed"
        if not b.exists():                              # it appears complete (atomic.py)
            return False
        with h5py.File(b, "r", locking=False) as f:
            return max(f["checkpoint/slot0/meta"][1], f["checkpoint/slot1/meta"][1]) >= 1000
    wait_until(checkpointed, "a checkpoint of step 1000 exists")
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL, "the run ended before it could be killed"
    with h5py.File(b, "r") as f:
        assert f["status"][()] != FINISHED
    result = hpcves("run", "--resume", b, "--quiet")
    assert result.returncode == 0, result.stderr
    compare_files(tmp_path / "a.h5", b)


def test_sigterm_checkpoints_and_exits_cleanly(tmp_path):
    b = tmp_path / "b.h5"
    case = write(tmp_path, SHORT.format(t_end=50.0, checkpoint=10.0))
    proc = subprocess.Popen(HPCVES + ["run", str(case), "--out", str(b), "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def stepping():                     # the handler is installed and steps were taken: samples are written
        assert proc.poll() is None, proc.communicate()
        if not b.exists():
            return False
        with h5py.File(b, "r", locking=False) as f:
            return int(f["timeseries/length"][()]) > 0
    wait_until(stepping, "the run has written samples")
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert "resume with: hpcves run --resume" in out
    with h5py.File(b, "r") as f:
        assert f["status"][()] == INTERRUPTED
        assert max(f["checkpoint/slot0/meta"][1], f["checkpoint/slot1/meta"][1]) > 0


def test_a_diverging_run_stops_with_a_message_and_keeps_its_checkpoint(tmp_path):
    # an area bound far below what the unprojected scheme does: the run "diverges" at
    # the first sample after the first checkpoints were written
    text = SHORT.format(t_end=1.0, checkpoint=0.002) + "max_area_error = 1e-7\n"
    text = text.replace("[run]", "[run]").replace("dt = 1e-3", "dt = 1e-3\narea_correction = false")
    out = tmp_path / "div.h5"
    result = hpcves("run", write(tmp_path, text), "--out", out, "--quiet")
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    assert "diverged" in result.stderr and "area" in result.stderr
    assert "last good checkpoint kept" in result.stderr
    with h5py.File(out, "r") as f:
        store = CaseStore.open(f)
        assert store.status == FAILED and "area" in store.message
        state, _, _ = store.read_checkpoint()
        assert np.all(np.isfinite(state.theta))


def test_a_run_at_the_model_limit_exits_0_and_is_not_resumed(tmp_path):
    from test_stepcontrol import DEFLATED  # the linear law: psi 1.08 near t = 2.74-2.92

    out = tmp_path / "limit.h5"
    result = hpcves("run", write(tmp_path, DEFLATED), "--out", out, "--quiet")
    assert result.returncode == 0, result.stderr
    stopped = re.match(rf"{re.escape(str(out))}: model limit at t = (\d\.\d+) ", result.stdout)
    assert stopped and 2.6 < float(stopped[1]) < 3.5, result.stdout   # the time: test_stepcontrol
    assert "model limit: psi in [" in result.stdout
    again = hpcves("run", "--resume", out)
    assert again.returncode == 0 and f"model limit already (t = {stopped[1]}); nothing to do" in again.stdout, \
        (again.stdout, again.stderr)


def test_the_start_up_of_a_deflated_vesicle_is_not_taken_for_divergence():
    """Delta = 0.94 at dt = 1e-3: the area projection undoes ~5e-3 of the area in the first steps
    (the initial ellipse relaxes fast), then < 1e-7 per step; that is not a divergence."""
    text = ("[physics]\nshear_rate = 5.0\npsi_bar = 0.0\nexcess_length = 0.94\n[numerics]\nN = 64\ndt = 1e-3\n"
            "[run]\nt_end = 0.1\nsample_interval = 0.01\nsnapshot_interval = 0.1\ncheckpoint_interval = 1.0\n")
    with h5py.File("start.h5", "w", driver="core", backing_store=False) as h5:
        store = CaseStore.create(h5, case_from_toml(text))
        out = runner.run(store, h5.flush)
        assert out.status == FINISHED, out.message
        series = store.timeseries()
        per_sample = np.diff(series["area_correction"])        # 10 steps per sample
        assert np.abs(per_sample[0]) > 1e-3                     # the start-up needs large corrections ...
        assert np.abs(per_sample[-3:]).max() < 1e-6             # ... and then hardly any
        assert np.abs(series["area_error"]).max() < 1e-10
    strict = text + "max_area_correction = 1e-3\n"               # the old bound stops it at once
    with h5py.File("strict.h5", "w", driver="core", backing_store=False) as h5:
        store = CaseStore.create(h5, case_from_toml(strict))
        out = runner.run(store, h5.flush)
        assert out.status == FAILED and "max_area_correction" in out.message


def downgrade_to_format_2(path):
    """Rewrite a case file as the format before adaptive steps wrote it: checkpoints without the
    time, the step controller and level n-2, nor the rheology series (the layout of hpcves before
    format 3)."""
    from hpcves.run.diagnostics import RHEOLOGY_SERIES
    from hpcves.run.store import _SCALAR_LAYOUTS
    width = sum(n for _, n in _SCALAR_LAYOUTS[2])
    with h5py.File(path, "r+") as f:
        f.attrs["format_version"] = 2
        del f["timeseries/digest"], f["snapshots/digest"]
        for name in RHEOLOGY_SERIES:
            del f[f"timeseries/{name}"]
        for slot in ("slot0", "slot1"):
            g = f[f"checkpoint/{slot}"]
            for name in ("prev2_theta", "prev2_psi", "digest"):
                del g[name]
            scalars = g["scalars"][:width]
            del g["scalars"]
            g.create_dataset("scalars", data=scalars)


def test_a_file_of_the_previous_format_is_read_and_resumes_bitwise(tmp_path):
    case = case_from_toml(SHORT.format(t_end=0.3, checkpoint=0.04))
    assert run_in_process(case, tmp_path / "a.h5").status == FINISHED
    assert run_in_process(case, tmp_path / "b.h5", max_steps=97).status == INTERRUPTED
    downgrade_to_format_2(tmp_path / "b.h5")

    def as_format_2(store):
        assert store.version == 2 and store.problems() == []
    assert resume_in_process(tmp_path / "b.h5", before=as_format_2).status == FINISHED
    compare_files(tmp_path / "a.h5", tmp_path / "b.h5")


def test_help_texts_show_no_markup():
    """What --help prints is read in a terminal: no reStructuredText backticks or roles."""
    from click.testing import CliRunner

    from hpcves.cli import main

    for command in ([], *[[name] for name in main.commands]):
        result = CliRunner().invoke(main, [*command, "--help"])
        assert result.exit_code == 0, result.output
        assert "``" not in result.output and ":func:" not in result.output and ":mod:" not in result.output, \
            (command, result.output)


def test_python_dash_m_hpcves_is_the_command_line():
    """``python -m hpcves`` (what a user without the script on PATH types) runs the same commands."""
    out = subprocess.run([sys.executable, "-m", "hpcves", "--help"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("Usage: hpcves ") and "campaign" in out.stdout


def test_the_commands_that_end_with_an_exit_status_say_which_in_their_help():
    from click.testing import CliRunner

    from hpcves.cli import main

    for command, words in (("run", "1 the computation diverged"), ("campaign", "1 a case failed"),
                           ("status", "3 work is left")):
        result = CliRunner().invoke(main, [command, "--help"])
        assert "Exit status: 0" in result.output and words in " ".join(result.output.split()), result.output


def test_status_of_a_toml_file_names_the_command_that_takes_it(tmp_path):
    """`hpcves status STUDY.toml` used to say "not a readable HDF5 file (corrupt or truncated?)"."""
    from click.testing import CliRunner

    from hpcves.cli import main

    study = write(tmp_path, '[campaign]\nname = "s"\noutput = "out/s.h5"\n[sweep]\nshear_rate = [1.0]\n', "s.toml")
    case = write(tmp_path, "[physics]\nshear_rate = 3.0\n", "c.toml")
    result = CliRunner().invoke(main, ["status", str(study)])
    assert result.exit_code == 2 and "`hpcves status out/s.h5`" in result.output
    assert f"`hpcves campaign {study}`" in result.output
    result = CliRunner().invoke(main, ["status", str(case)])
    assert result.exit_code == 2 and f"`hpcves run {case} --out FILE.h5`" in result.output


def test_run_points_a_study_file_and_a_campaign_file_to_campaign(tmp_path):
    from click.testing import CliRunner

    from hpcves.cli import main

    study = write(tmp_path, '[campaign]\nname = "s"\noutput = "s.h5"\n[sweep]\nshear_rate = [1.0]\n', "s.toml")
    result = CliRunner().invoke(main, ["run", str(study), "--out", str(tmp_path / "x.h5")])
    assert result.exit_code == 2 and f"`hpcves campaign {study}` runs it" in result.output
    assert not (tmp_path / "x.h5").exists()
    campaign = tmp_path / "c.h5"
    with h5py.File(campaign, "w") as h5:
        from hpcves.campaign.file import FORMAT
        h5.attrs["format"] = FORMAT
    result = CliRunner().invoke(main, ["run", "--resume", str(campaign)])
    assert result.exit_code == 2 and "`hpcves campaign STUDY.toml --resume` continues it" in result.output


def test_status_counts_a_case_that_ended_early_as_done(capsys):
    """A case decided (or failed) before t_end used to leave 'simulated time 50 % done ... complete'."""
    from types import SimpleNamespace

    from hpcves.cli.status import _status_table

    rows = [{"case": "0000", "shear_rate": 1.0, "status": "finished", "t": 2.0, "t_end": 4.0, "wall": 1.0,
             "steps_per_second": 10.0, "message": "decided TT"},
            {"case": "0001", "shear_rate": 2.0, "status": "finished", "t": 4.0, "t_end": 4.0, "wall": 1.0,
             "steps_per_second": 10.0, "message": ""}]
    _status_table("s", rows, {"finished": 2}, "no campaign is writing it",
                  SimpleNamespace(complete=True, failed=0, left=""))
    last = capsys.readouterr().out.splitlines()[-1]
    assert "simulated time 100 % done (1 case ended before t_end" in last and last.endswith("complete")
