"""Hostile inputs get one line and exit 2, with nothing left behind (issue 64, item 3), and the small
stumbles of a newcomer's first hour (item 5) -- each class with more than its one reported example.

In process (click's test runner) where that suffices; ``--plan`` refusals are checked to come before
the step is timed (nothing but the refusal on stderr).
"""
import os

import pytest
from click.testing import CliRunner

from conftest import TINY_RUN, tiny_study
from hpcves.cli import main

BASE_RUN = ("[numerics]\nN = 32\ndt = 1e-3\n[run]\nmax_spectral_tail = 1.0\nt_end = 0.02\nsample_interval = 0.005\n"
            "snapshot_interval = 0.01\n")


def invoke(*args, env=None):
    result = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=True, env=env)
    assert result.exception is None or isinstance(result.exception, SystemExit), \
        f"{type(result.exception).__name__}: {result.exception}"
    return result


def refused(result) -> str:
    """The one ``Error:`` line of a refusal with exit status 2 and no traceback."""
    assert result.exit_code == 2, (result.exit_code, result.stdout, result.stderr)
    assert "Traceback" not in result.stderr + result.stdout
    lines = [line for line in result.stderr.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error: "), result.stderr
    return lines[0]


def study(directory, name="h", extra="", output=None, **settings):
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{name}.toml"
    path.write_text(tiny_study(output or directory / f"{name}.h5", name=name, t_end=0.01, shear="[40]", psi="[0.3]",
                               extra=extra, **settings))
    return path


# ---------------------------------------------------------------------- batch scripts
@pytest.mark.parametrize("where", ["the study's directory", "the script's directory", "the output's directory"])
def test_a_line_break_in_a_path_of_the_batch_script_is_refused_before_the_timing(tmp_path, where):
    """A newline in the study's directory name ended the script's comment line and `$(id)` ran."""
    evil = tmp_path / "a\n$(touch pwned)"
    study_dir = evil if where == "the study's directory" else tmp_path / "s"
    script_dir = evil if where == "the script's directory" else tmp_path
    study_file = study(study_dir, output=tmp_path / "o.h5")
    script_dir.mkdir(exist_ok=True)
    args = ["campaign", study_file, "--plan", "--slurm", script_dir / "job.sh"]
    if where == "the output's directory":
        evil.mkdir()
        args += ["--out", evil / "o.h5"]
    line = refused(invoke(*args))
    assert "holds a line break or another control character" in line and "rename it" in line, line
    assert not (script_dir / "job.sh").exists()


def test_a_study_name_with_spaces_makes_a_job_name_sbatch_reads_whole(tmp_path):
    from hpcves.campaign.slurm import JobSize, slurm_script

    text = slurm_script(script=tmp_path / "j.sh", study_name="my study; rm -rf ~", study_file=tmp_path / "s.toml",
                        output=tmp_path / "o.h5", size=JobSize(2, 3600, 2**29, 3), hpcves=tmp_path / "hpcves",
                        python=tmp_path / "python", workdir=tmp_path, stop_timeout=10.0, summary="s",
                        largest_N=32)
    assert "#SBATCH --job-name=hpcves-my_study__rm_-rf__\n" in text
    assert "#SBATCH --output=hpcves-my_study__rm_-rf__-%j.log\n" in text


@pytest.mark.parametrize("kind", ["binary", "fifo", "device", "a placeholder that is not a word", "huge"])
def test_a_template_that_is_no_template_is_refused_in_one_line_before_the_timing(tmp_path, kind):
    """--slurm-template of a binary file: a traceback; a FIFO or /dev/zero: a hang; {{ job-name }}: left
    in the script."""
    study_file = study(tmp_path / "s")
    template = tmp_path / "site.sh"
    if kind == "binary":
        template.write_bytes(bytes(range(256)))
    elif kind == "fifo":
        os.mkfifo(template)
    elif kind == "device":
        template = "/dev/zero"
    elif kind == "huge":
        template.write_text("#!/bin/bash\n" + "# padding\n" * 200_000)
    else:
        template.write_text("#!/bin/bash\n#SBATCH --job-name={{ job-name }}\n#SBATCH --signal=TERM@60\n")
    line = refused(invoke("campaign", study_file, "--plan", "--slurm", tmp_path / "job.sh",
                          "--slurm-template", template))
    words = {"binary": "not UTF-8 text", "fifo": "a named pipe, not a template file",
             "device": "a character device, not a template file", "huge": "not a template",
             "a placeholder that is not a word": "'{{ job-name }}' is not a placeholder"}[kind]
    assert words in line, line
    assert not (tmp_path / "job.sh").exists()


# ---------------------------------------------------------------------- study and case files
@pytest.mark.parametrize("table, key", [("analysis", "min_cycles"), ("analysis", "rel_tol"), ("search", "rel_tol"),
                                        ("search", "high")])
@pytest.mark.parametrize("value", ["inf", "nan"])
def test_a_non_finite_setting_is_refused_in_one_line(tmp_path, table, key, value):
    """[analysis] min_cycles = inf: every case failed as "diverged" and analyze crashed with a traceback."""
    path = tmp_path / "s.toml"
    head = f'[campaign]\nname = "s"\noutput = "{tmp_path / "s.h5"}"\nt_end = 0.01\n' + TINY_RUN.format(checkpoint=0.05)
    if table == "search":
        search = {"low": "10.0", "high": "100.0", key: value}
        path.write_text(head + "[sweep]\npsi_bar = [0.3]\n[search]\n"
                        + "".join(f"{k} = {v}\n" for k, v in search.items()))
    else:
        path.write_text(head + f"[sweep]\nshear_rate = [40]\n[{table}]\n{key} = {value}\n")
    line = refused(invoke("campaign", path))
    assert f"{table}.{key} = {value}: must be a finite number" in line, line
    assert not (tmp_path / "s.h5").exists()


@pytest.mark.parametrize("value", ["inf", "nan", "-inf"])
def test_analyze_set_refuses_a_non_finite_threshold(tmp_path, value):
    case = tmp_path / "c.toml"
    case.write_text(BASE_RUN)
    assert invoke("run", case, "--out", tmp_path / "c.h5", "--quiet").exit_code == 0
    line = refused(invoke("analyze", tmp_path / "c.h5", "--set", f"min_cycles={value}", "--out", tmp_path / "a"))
    assert f"analysis.min_cycles = {value}: must be a finite number" in line, line


@pytest.mark.parametrize("name", ["a/b", "a\\nb", " lead", "", "-dash", "x" * 65])
def test_a_start_name_that_cannot_label_a_table_or_file_is_refused(tmp_path, name):
    """Start names with '/' or a line break: the campaign ran, then could not be analysed (or wrote
    file names with a line break)."""
    key = '"' + name.replace("\\", "\\\\").replace("\n", "\\n") + '"'
    path = tmp_path / "s.toml"
    path.write_text(tiny_study(tmp_path / "s.h5", name="s", t_end=0.01, shear="[40]", psi="[0.3]",
                               extra=f"[starts]\nellipse = {{}}\n{key} = {{ initial_shape = \"smoothed\" }}\n"))
    line = refused(invoke("campaign", path))
    assert "[starts]: the name" in line and "letters, digits" in line, line
    assert not (tmp_path / "s.h5").exists()


@pytest.mark.parametrize("value, words", [(33, "numerics.N_min = 33: must be even"),
                                          (8, "numerics.N_min = 8: must be even, from 16"),
                                          (1.5, "numerics.N_min = 1.5: must be an integer")])
def test_N_min_is_named_N_min(tmp_path, value, words):
    case = tmp_path / "c.toml"
    case.write_text(f'[numerics]\nN = "auto"\nN_min = {value}\n')
    line = refused(invoke("run", case, "--out", tmp_path / "c.h5"))
    assert words in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml"]


def test_a_refused_stored_start_leaves_no_file_and_the_rerun_is_not_refused_for_it(tmp_path):
    """The run's file was made before its stored start was read; the refused start left it behind,
    and the corrected rerun was refused: the file exists already."""
    case = tmp_path / "c.toml"
    case.write_text(BASE_RUN + f'[physics]\ninitial_shape = "stored"\nstored_file = "{tmp_path / "none.h5"}"\n')
    line = refused(invoke("run", case, "--out", tmp_path / "c.h5"))
    assert "physics.stored_file" in line and "no such file" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml"]
    source = tmp_path / "source.toml"
    source.write_text(BASE_RUN)
    assert invoke("run", source, "--out", tmp_path / "none.h5", "--quiet").exit_code == 0
    assert invoke("run", case, "--out", tmp_path / "c.h5", "--quiet").exit_code == 0


@pytest.mark.parametrize("spec", ["checkpoint:x", "nowhere", "checkpoint:0", "checkpoint@rank", "publish:2@"])
def test_a_malformed_fault_variable_is_one_line(tmp_path, spec, monkeypatch):
    from hpcves.files import faults

    monkeypatch.setattr(faults, "_SPEC", spec)
    line = refused(invoke("status", tmp_path / "none.h5"))
    assert f"HPCVES_FAULT={spec!r}: not point[:n][@rank]" in line, line


@pytest.mark.parametrize("out, words", [("x.txt", "matplotlib writes no figure format '.txt'"),
                                        ("x", "matplotlib writes no figure format '(none)'")])
def test_shapes_out_of_a_format_matplotlib_cannot_write_is_one_line(tmp_path, out, words):
    line = refused(invoke("shapes", tmp_path / "none.h5", "--case", "0000", "--out", tmp_path / out))
    assert words in line, line
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------- the Python API's words
def test_api_errors_name_the_api_arguments_not_the_command_lines_options(tmp_path):
    """A notebook user was told to use --overwrite."""
    import hpcves
    from hpcves.errors import HpcvesError

    case = tmp_path / "c.toml"
    case.write_text(BASE_RUN)
    out = tmp_path / "c.h5"
    hpcves.run_case(str(case), out, progress=False)
    with pytest.raises(HpcvesError, match=r"exists already \(use overwrite=True to replace it\)"):
        hpcves.run_case(str(case), out, progress=False)
    study_file = study(tmp_path / "s")
    assert hpcves.run_campaign(str(study_file), progress=False).exit_status == 0
    with pytest.raises(HpcvesError, match="use resume=True to continue it or overwrite=True to start over"):
        hpcves.run_campaign(str(study_file), progress=False)


@pytest.mark.parametrize("table, key, value, home", [("physics", "N", "64", "numerics"),
                                                      ("numerics", "shear_rate", "40.0", "physics"),
                                                      ("physics", "t_end", "1.0", "run"),
                                                      ("run", "N_min", "32", "numerics")])
def test_a_key_in_the_wrong_table_says_which_table_it_belongs_in(tmp_path, table, key, value, home):
    case = tmp_path / "c.toml"
    case.write_text(f"[{table}]\n{key} = {value}\n")
    line = refused(invoke("run", case, "--out", tmp_path / "c.h5"))
    assert f"[{table}]: unknown key {key} (it belongs in [{home}])" in line, line


def test_the_bar_of_a_finished_run_reaches_100_percent(tmp_path, monkeypatch):
    """The tqdm bar of a run that finished stopped at its last tick (99 %, or less for a decided run)."""
    import types

    import hpcves
    from hpcves import api

    shown = []

    class Watched(api.CaseBar):
        def close(self, done=False):
            self(types.SimpleNamespace(t=0.5, t_end=1.0, steps_per_second=1.0, theta=0.0))   # a last tick short
            super().close(done)
            shown.append((self.bar.n, self.bar.total, done))

    monkeypatch.setattr(api, "CaseBar", Watched)
    case = tmp_path / "c.toml"
    case.write_text(BASE_RUN)
    hpcves.run_case(str(case), tmp_path / "c.h5")
    assert shown == [(1.0, 1.0, True)]
    hpcves.run_case(None, tmp_path / "c.h5", resume=True)            # finished already: full too
    cut = tmp_path / "cut.h5"
    hpcves.run_case(str(case), cut, max_steps=5)                     # stopped part way: where it stopped
    assert shown[-1] == (0.5, 1.0, False)


def test_analyzes_summary_says_where_the_case_pages_are(tmp_path):
    case = tmp_path / "c.toml"
    case.write_text(BASE_RUN)
    assert invoke("run", case, "--out", tmp_path / "c.h5", "--quiet").exit_code == 0
    drawn = invoke("analyze", tmp_path / "c.h5", "--out", tmp_path / "a", "--no-streamlines")
    assert drawn.exit_code == 0, drawn.stderr
    assert f"case pages (1): {tmp_path / 'a' / 'cases'}/<case>.png" in drawn.stdout, drawn.stdout
    assert (tmp_path / "a" / "cases").is_dir()
    none = invoke("analyze", tmp_path / "c.h5", "--out", tmp_path / "b", "--no-case-figures")
    assert "case pages: none drawn" in none.stdout, none.stdout


@pytest.mark.parametrize("warm", [False, True])
def test_a_first_run_says_it_compiles_instead_of_sitting_at_t_0(tmp_path, monkeypatch, warm):
    from hpcves.solver import compiled

    monkeypatch.setattr(compiled, "cache_is_warm", lambda: warm)
    case = tmp_path / "c.toml"
    case.write_text(BASE_RUN)
    result = invoke("run", case, "--out", tmp_path / "c.h5")
    assert result.exit_code == 0, result.stderr
    assert ("compiling the time step" in result.stderr) is not warm, result.stderr


def test_numbas_cache_index_answers_whether_the_step_is_compiled(tmp_path):
    """cache_is_warm asks numba's private cache index: with this numba it answers (a run compiled or
    loaded the kernels, so they are on disk), and for a cache directory of its own with nothing in it,
    it says cold."""
    import subprocess
    import sys

    case = tmp_path / "c.toml"
    case.write_text(BASE_RUN)
    assert invoke("run", case, "--out", tmp_path / "c.h5", "--quiet").exit_code == 0
    from hpcves.solver.compiled import cache_is_warm

    assert cache_is_warm() is True
    cold = subprocess.run([sys.executable, "-c", "from hpcves.solver.compiled import cache_is_warm; "
                           "print(cache_is_warm())"], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "empty")})
    assert cold.stdout.strip() == "False", cold.stderr


@pytest.mark.parametrize("progress", ["", "log"])
def test_mpirun_from_a_terminal_shows_live_progress(tmp_path, progress):
    """Under mpirun rank 0's stderr is a pipe, so a user at a terminal saw one line and the summary; the
    launcher's own stderr says whether a person watches (a batch job's goes to its log: one line every
    30 s there). Run in a pseudo-terminal (util-linux's script)."""
    import shutil
    import subprocess

    from jobs import MPIRUN, mpi_env

    if MPIRUN is None or shutil.which("script") is None:
        pytest.skip("needs mpirun and script(1)")
    study_file = study(tmp_path / "s")
    typescript = tmp_path / "typescript"
    hpcves = shutil.which("hpcves") or os.path.join(os.path.dirname(os.sys.executable), "hpcves")
    command = f"{MPIRUN} -n 2 {hpcves} campaign {study_file}"
    env = dict(mpi_env(), HPCVES_PROGRESS=progress)
    done = subprocess.run(["script", "-qec", command, str(typescript)], env=env, capture_output=True,
                          timeout=600)
    assert done.returncode == 0, done.stdout.decode(errors="replace")
    shown = typescript.read_bytes().decode(errors="replace")
    assert "cases |" in shown, shown
    assert ("\r[" in shown) is (progress != "log"), repr(shown[-600:])


def test_every_fault_point_in_the_package_is_one_the_variable_may_name():
    """The list HPCVES_FAULT is checked against must hold every point the code passes (it missed
    verdicts-stored, which the scale tests kill at: they would have been refused)."""
    import re
    from pathlib import Path

    from hpcves.files import faults

    root = Path(faults.__file__).resolve().parents[1]
    used = {m for path in root.rglob("*.py") for m in re.findall(r'faults\.point\("([a-z-]+)"\)', path.read_text())}
    assert used and used == set(faults.POINTS), (used, faults.POINTS)
    for point in used:
        assert faults._parse(f"{point}:2@1") == (point, 2, 1)


@pytest.mark.parametrize("command", [("run", "{case}", "--out", "{evil}"), ("run", "--resume", "{evil}"),
                                     ("campaign", "{evil}"), ("status", "{evil}"), ("analyze", "{evil}"),
                                     ("shapes", "{evil}"), ("animate", "{evil}")])
def test_a_file_name_with_a_line_break_gets_one_line_from_every_command(tmp_path, command):
    """A path with a newline in its name printed as two lines in every message that named it."""
    case = tmp_path / "case.toml"
    case.write_text(BASE_RUN)
    evil = tmp_path / "a\nb.h5"
    line = refused(invoke(*[a.format(case=case, evil=evil) for a in command]))
    assert line.startswith(f"Error: {str(evil)!r}: the name holds a line break") and "rename it" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["case.toml"]
