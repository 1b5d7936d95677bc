"""Over a hundred malformed inputs and damaged files: each one line on stderr and exit status 2, never a
traceback (issue 14). Case files for ``hpcves run``, study files for ``hpcves campaign``, damaged
campaign files for ``status --check``, ``analyze`` and ``campaign --resume``, damaged run files for
``run --resume`` and ``analyze``. In process (click's test runner), so the corpus takes seconds.
"""
import os

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from hpcves.campaign.driver import run_campaign
from hpcves.campaign.study import study_from_toml
from hpcves.cli import main
from hpcves.config import case_from_toml
from hpcves.run import runner
from hpcves.run.blocks import QUANTITIES
from hpcves.run.store import CaseStore
from jobs import case_view, writing_format

BASE_RUN = ("[numerics]\nN = 32\ndt = 1e-3\n[run]\nmax_spectral_tail = 1.0\nt_end = 0.02\nsample_interval = 0.005\n"
            "snapshot_interval = 0.01\n")

#: case files: (text, words the one line must hold)
CASE_FILES = {
    "unknown key": ("[physics]\nshear = 3\n", "[physics]: unknown key shear (did you mean shear_rate?)"),
    "unknown table": ("[physic]\nshear_rate = 3\n", "unknown table: [physic] (did you mean [physics]?)"),
    "a typo": ("[numerics]\nrtoll = 1e-3\n", "[numerics]: unknown key rtoll (did you mean rtol?)"),
    "a key like none": ("[physics]\ntension = 3\n", "[physics]: unknown key tension (known: "),
    "a table that is a number": ("physics = 3\n", "[physics] must be a table"),
    "nested table": ("[physics.more]\nx = 1\n", "[physics]: unknown key more"),
    "float for N": ("[numerics]\nN = 64.5\n", "numerics.N = 64.5: must be an integer"),
    "bool for N": ("[numerics]\nN = true\n", "numerics.N = True: must be an integer"),
    "string for a number": ('[run]\nt_end = "5"\n', "run.t_end = '5': must be a number"),
    "array for a number": ("[physics]\npsi_bar = [0.3]\n", "physics.psi_bar = [0.3]: must be a number"),
    "N odd": ("[numerics]\nN = 63\n", "numerics.N = 63: must be even"),
    "N too small": ("[numerics]\nN = 8\n", "numerics.N = 8: too small"),
    "N too large": ("[numerics]\nN = 8192\n", "numerics.N = 8192: more than 4096"),
    "dt zero": ("[numerics]\ndt = 0.0\n", "numerics.dt = 0.0: must be > 0"),
    "dt nan": ("[numerics]\ndt = nan\n", "numerics.dt = nan: must be a finite number"),
    "t_end inf": ("[run]\nt_end = inf\n", "run.t_end = inf: must be a finite number"),
    "t_end negative": ("[run]\nt_end = -1.0\n", "run.t_end = -1.0: must be > 0"),
    "t_end below dt": ("[numerics]\ndt = 1e-2\n[run]\nt_end = 1e-3\n", "is shorter than numerics.dt"),
    "sample interval zero": ("[run]\nsample_interval = 0.0\n", "run.sample_interval = 0.0: must be > 0"),
    "sample interval below dt": ("[run]\nsample_interval = 1e-4\n", "is shorter than numerics.dt"),
    "snapshot interval negative": ("[run]\nsnapshot_interval = -1.0\n", "run.snapshot_interval = -1.0"),
    "checkpoint wall negative": ("[run]\ncheckpoint_wall = -1.0\n", "run.checkpoint_wall = -1.0: must be >= 0"),
    "psi_min positive": ("[run]\npsi_min = 0.1\n", "need psi_min < 0 and psi_max > 1"),
    "psi_max below 1": ("[run]\npsi_max = 0.9\n", "need psi_min < 0 and psi_max > 1"),
    "area bound zero": ("[run]\nmax_area_error = 0.0\n", "run.max_area_error = 0.0: must be > 0"),
    "B1 zero": ("[physics]\nB1 = 0.0\n", "physics.B1 = 0.0: bending stiffness must be > 0"),
    "B2 negative": ("[physics]\nB2 = -1.0\n", "physics.B2 = -1.0"),
    "epsilon zero": ("[physics]\nepsilon = 0.0\n", "physics.epsilon = 0.0: must be > 0"),
    "mobility zero": ("[physics]\nmobility = 0.0\n", "physics.mobility = 0.0: must be > 0"),
    "delta negative": ("[physics]\ndelta = -0.1\n", "physics.delta = -0.1: must be >= 0"),
    "excess length huge": ("[physics]\nexcess_length = 25.0\n", "aspect ratio beyond 1:1000"),
    "excess length negative": ("[physics]\nexcess_length = -0.05\n", "no ellipse"),
    "length zero": ("[physics]\nlength = 0.0\n", "physics.length = 0.0: must be > 0"),
    "a0 negative": ("[physics]\na0 = -1.0\n", "physics.a0 = -1.0"),
    "shear rate negative": ("[physics]\nshear_rate = -5.0\n", "physics.shear_rate = -5.0: must be >= 0"),
    "psi_bar above 1": ("[physics]\npsi_bar = 1.2\n", "physics.psi_bar = 1.2: must lie in [0, 1]"),
    "initial psi out of range": ("[physics]\npsi_bar = 0.9\ndelta = 0.1\n", "the initial psi spans"),
    "bending stabilization below 1": ("[numerics]\nbending_stabilization = 0.5\n", "must be >= 1"),
    "phase stabilization below 1/2": ("[numerics]\nphase_stabilization = 0.1\n", "must be >= 0.5"),
    "area correction not a bool": ("[numerics]\narea_correction = 1\n", "must be true or false"),
    "bad choice": ('[physics]\npsi_init_coordinate = "polar"\n', "must be one of 'arclength'"),
    "choice not a string": ("[physics]\npsi_init_coordinate = 3\n", "psi_init_coordinate = 3"),
    "a billion seconds": ("[numerics]\ndt = 1e-3\n[run]\nt_end = 1e9\n", "1e+12 time steps"),
    "a femtosecond step": ("[numerics]\ndt = 1e-15\n", "1e+15 time steps"),
    "not TOML": ("[physics\nshear_rate = 1\n", "not valid TOML"),
    "a key twice": ("[physics]\nshear_rate = 1.0\nshear_rate = 2.0\n", "not valid TOML"),
    "not UTF-8": (b"[physics]\n# B\xe4r\nshear_rate = 1.0\n", "not UTF-8 text (byte 0xe4"),
    "binary": (bytes(range(256)) * 4, "not UTF-8 text"),
    "empty": ("", "sets nothing (empty, or comments only); give at least one of [physics]"),
    "comments only": ("# a case\n\n   # to come\n", "sets nothing (empty, or comments only)"),
    "an absurd shear rate": ("[physics]\nshear_rate = 1e26\n", "physics.shear_rate = 1e+26: beyond 1e+12"),
    "a shear rate past the model": ("[physics]\nshear_rate = 2e6\n", "physics.shear_rate = 2e+06: at most 1e+06"),
    "an absurd length": ("[physics]\nlength = 1e300\n", "physics.length = 1e+300: beyond 1e+12"),
    "a date for a number": ("[run]\nt_end = 1979-05-27\n", "run.t_end = datetime.date(1979, 5, 27): must be a number"),
    "a time for a number": ("[run]\nt_end = 07:32:00\n", "must be a number"),
    "an inline table for a number": ("[physics]\nshear_rate = { a = 1 }\n", "physics.shear_rate = {'a': 1}"),
    "a 23-digit N": ("[numerics]\nN = 99999999999999999999999\n", "more than 4096 points"),
    "dt of minus zero": ("[numerics]\ndt = -0.0\n", "numerics.dt = -0.0: must be > 0"),
    "a NUL byte": ("[physics]\nshear_rate = 1.0\x00\n", "not valid TOML"),
    "an array of tables": ("[[physics]]\nshear_rate = 1.0\n", "[physics] must be a table"),
    "a number past a double": ("[physics]\nshear_rate = 1e400\n", "physics.shear_rate = inf: must be a finite"),
    "dealias 3": ("[numerics]\ndealias = 3\n", "numerics.dealias = 3.0: must be 1"),
    "N_max below N_min": ("[numerics]\nN = 'auto'\nN_min = 128\nN_max = 64\n", "numerics.N_max = 64: must be above"),
    # session 33: TOML edge cases, other encodings and other tools' files, options past their ranges
    "UTF-16 text": ("[physics]\nshear_rate = 3.0\n".encode("utf-16"), "not UTF-8 text (byte 0xff at offset 0)"),
    "a table declared twice": ("[physics]\nshear_rate = 1.0\n[physics]\npsi_bar = 0.3\n", "not valid TOML"),
    "an integer past 64 bits": ("[numerics]\nN = 99999999999999999999999\n", "numerics.N = 99999999999999999999999"),
    "dt negative zero": ("[numerics]\ndt = -0.0\n", "numerics.dt = -0.0: must be > 0"),
    "dt underflowing to 0": ("[numerics]\ndt = 1e-400\n", "numerics.dt = 0.0: must be > 0"),
    "t_end overflowing to inf": ("[run]\nt_end = 1e400\n", "run.t_end = inf: must be a finite number"),
    "an unterminated string": ('[physics]\nbending_law = "linear\n', "not valid TOML"),
    "a key without a value": ("[physics]\nshear_rate =\n", "not valid TOML"),
    "an unknown bending law": ('[physics]\nbending_law = "cubic"\n', "physics.bending_law = 'cubic': must be one of"),
    "a bending law by number": ("[physics]\nbending_law = 3\n", "physics.bending_law = 3: must be one of"),
    "an unknown initial shape": ('[physics]\ninitial_shape = "star"\n', "physics.initial_shape = 'star'"),
    "an unknown psi coordinate": ('[physics]\npsi_init_coordinate = "angle"\n', "physics.psi_init_coordinate"),
    "no phase domain": ("[physics]\nphase_domains = 0\n", "physics.phase_domains = 0: must be an integer from 1"),
    "a stored start without its file": ('[physics]\ninitial_shape = "stored"\n', "needs physics.stored_file"),
    "filter order 4": ("[numerics]\nfilter_order = 4\n", "numerics.filter_order = 4: must be 0"),
    "rtol 0.5": ("[numerics]\nrtol = 0.5\n", "numerics.rtol = 0.5: must lie in [1e-10, 0.1]"),
    "N_max below a fixed N": ("[numerics]\nN = 64\nN_max = 32\n", "numerics.N_max = 32: must be above N = 64"),
    "resize_tail 1": ('[numerics]\nN = "auto"\nresize_tail = 1.0\n', "numerics.resize_tail = 1.0: must lie in (0, 1)"),
    "shrink_after 0": ('[numerics]\nN = "auto"\nshrink_after = 0.0\n', "numerics.shrink_after = 0.0: must be > 0"),
    "N a word": ('[numerics]\nN = "many"\n', "numerics.N = 'many': must be an integer, or \"auto\""),
    "until_decided a string": ('[run]\nuntil_decided = "yes"\n', "run.until_decided = 'yes': must be true or false"),
    "area_correction a number": ("[numerics]\narea_correction = 1\n", "numerics.area_correction = 1: must be true"),
    "a JSON file": ('{"physics": {"shear_rate": 3}}\n', "not valid TOML"),
    "a YAML file": ("physics:\n  shear_rate: 3\n", "not valid TOML"),
    "a zip archive": (b"PK\x03\x04\x14\x00\x00\x00\x08\x00" + bytes(range(40)), "not valid TOML"),
    "a PNG image": (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(30), "not UTF-8 text (byte 0x89 at offset 0)"),
    "an HDF5 file": (b"\x89HDF\r\n\x1a\n" + bytes(100), "not UTF-8 text (byte 0x89 at offset 0)"),
}

STUDY_HEAD = '[campaign]\nname = "bad"\nt_end = 0.02\n' + BASE_RUN

#: study files: (text, words); ``{head}`` is a sound [campaign] table with the tiny numerics
STUDY_FILES = {
    "unknown campaign key": ('[campaign]\nnmae = "x"\n', "[campaign]: unknown key nmae"),
    "campaign not a table": ("campaign = 3\n", "[campaign] must be a table"),
    "empty name": ('[campaign]\nname = ""\n', "campaign.name = '': must be a non-empty string"),
    "name a number": ("[campaign]\nname = 3\n", "campaign.name = 3"),
    "empty output": ('[campaign]\noutput = ""\n', "campaign.output = '': must be a file path"),
    "output a number": ("[campaign]\noutput = 5\n", "campaign.output = 5"),
    "t_end and shear_times": ("[campaign]\nt_end = 1.0\nshear_times = 10\n", "give t_end or shear_times, not both"),
    "shear_times zero": ("[campaign]\nshear_times = 0\n", "campaign.shear_times = 0.0: must be > 0"),
    "t_end_min negative": ("[campaign]\nt_end_min = -1.0\n", "campaign.t_end_min = -1.0: must be >= 0"),
    "campaign t_end zero": ("[campaign]\nt_end = 0.0\n", "campaign.t_end = 0.0: must be > 0"),
    "samples per shear time zero": ("[campaign]\nsamples_per_shear_time = 0\n", "must be > 0"),
    "stop timeout zero": ("[campaign]\nstop_timeout = 0.0\n", "campaign.stop_timeout = 0.0: must be > 0"),
    "stop timeout a string": ('[campaign]\nstop_timeout = "x"\n', "campaign.stop_timeout = 'x'"),
    "sweep over N": ("{head}[sweep]\nN = [32, 64]\n", "sweep over N: only shear_rate"),
    "empty sweep list": ("{head}[sweep]\nshear_rate = []\n", "sweep.shear_rate: empty list"),
    "sweep a string": ('{head}[sweep]\nshear_rate = "abc"\n', "sweep.shear_rate = 'abc'"),
    "linspace of two": ("{head}[sweep]\nshear_rate = {{ linspace = [1, 2] }}\n", "must be [start, stop, num]"),
    "linspace of none": ("{head}[sweep]\nshear_rate = {{ linspace = [1, 2, 0] }}\n", "num = 0 must lie in"),
    "linspace of a float": ("{head}[sweep]\nshear_rate = {{ linspace = [1, 2, 2.5] }}\n", "must be an integer"),
    "logspace from 0": ("{head}[sweep]\nshear_rate = {{ logspace = [0, 10, 3] }}\n", "start and stop must be > 0"),
    "arange": ("{head}[sweep]\nshear_rate = {{ arange = [1, 10, 1] }}\n", "use a list, a number"),
    "two spacings": ("{head}[sweep]\nshear_rate = {{ linspace = [1, 2, 3], logspace = [1, 2, 3] }}\n",
                     "use a list, a number"),
    "a value twice": ("{head}[sweep]\nshear_rate = [40, 40]\n", "sweep.shear_rate: 40 (2 times)"),
    "logspace of one value": ("{head}[sweep]\nshear_rate = {{ logspace = [40, 40, 3] }}\n", "40 (3 times)"),
    "a string in a list": ('{head}[sweep]\nshear_rate = [40, "a"]\n', "sweep.shear_rate[1] = 'a'"),
    "bool in a sweep": ("{head}[sweep]\nshear_rate = true\n", "sweep.shear_rate = True"),
    "a case out of range": ("{head}[sweep]\npsi_bar = [0.3, 1.5]\n", "case 0001 (psi_bar = 1.5): physics.psi_bar"),
    "a negative shear rate": ("{head}[sweep]\nshear_rate = [-1, 10]\n", "case 0000 (shear_rate = -1)"),
    "far too many cases": ("{head}[sweep]\nshear_rate = {{ linspace = [1, 2, 1000] }}\n"
                           "psi_bar = {{ linspace = [0.3, 0.4, 1000] }}\n", "has 1000000 cases"),
    "a huge linspace": ("{head}[sweep]\nshear_rate = {{ linspace = [1, 2, 1000000000] }}\n", "must lie in [1, 100000]"),
    "base case wrong": ("[numerics]\nN = 7\n", "base case: numerics.N = 7"),
    "zero shear without a floor": ("[campaign]\nshear_times = 10\n[sweep]\nshear_rate = [0, 10]\n",
                                   "shear_rate = 0 has no shear time"),
    "search low above high": ("{head}[search]\nlow = 100.0\nhigh = 10.0\n", "low < high"),
    "search without high": ("{head}[search]\nlow = 10.0\n", "give high"),
    "search unknown key": ("{head}[search]\nlow = 10.0\nhigh = 100.0\nspan = 3\n", "unknown key span"),
    "search over the shear rate": ("{head}[search]\nlow = 10.0\nhigh = 100.0\n[sweep]\nshear_rate = [1, 2]\n",
                                   "leave shear_rate out of [sweep]"),
    "search a table that is not": ("search = 3\n{head}", "[search] must be a table"),
    "analysis unknown key": ("{head}[analysis]\nmincycles = 3\n", "unknown key mincycles"),
    "analysis a string": ('{head}[analysis]\nmin_cycles = "x"\n', "analysis.min_cycles = 'x'"),
    "not TOML": ("[campaign\n", "not valid TOML"),
    "not UTF-8": (b'[campaign]\nname = "b\xe4d"\n', "not UTF-8 text (byte 0xe4"),
    "empty": ("", "sets nothing (empty, or comments only); give at least one of [campaign]"),
    "comments only": ("# the study\n", "sets nothing (empty, or comments only)"),
    "stop timeout beyond a day": ("[campaign]\nstop_timeout = 1e308\n", "must be > 0 seconds and at most 86400"),
    "a name with a slash": ('[campaign]\nname = "a/b"\n', "campaign.name = 'a/b': letters, digits"),
    "a name with a line break": ('[campaign]\nname = "a\\nb"\n', "campaign.name = 'a\\nb'"),
    "a name with a tab": ('[campaign]\nname = "a\\tb"\n', "campaign.name = 'a\\tb'"),
    "a name with spaces around": ('[campaign]\nname = " a "\n', "campaign.name = ' a '"),
    "an output ending in a slash": ('[campaign]\noutput = "out/"\n', "campaign.output = 'out/'"),
    "a name of 5000 characters": ("[campaign]\nname = '" + "x" * 5000 + "'\n", "5000 characters, at most 200"),
    "a sample every 1e-12 shear times": ("[campaign]\nshear_times = 10\nsamples_per_shear_time = 1e12\n"
                                         "[sweep]\nshear_rate = [1, 2]\n", "must be > 0 and at most 1e4"),
    "an output of /": ("[campaign]\noutput = '/'\n", "campaign.output = '/'"),
    "a list in a sweep list": ("{head}[sweep]\nshear_rate = [[1, 2]]\n", "sweep.shear_rate[0] = [1, 2]"),
    "a start that is a number": ("{head}[sweep]\nshear_rate = [1, 10]\n[starts]\na = 3\n", "starts.a = 3"),
    "a negative refine tolerance": ("{head}[sweep]\nshear_rate = [1, 10]\npsi_bar = [0.3, 0.5]\n[refine]\n"
                                    "tolerance = {{ shear_rate = -0.1, psi_bar = 0.05 }}\n",
                                    "tolerance.shear_rate = -0.1: must be > 0"),
    "a swept shear rate past the model": ("{head}[sweep]\nshear_rate = [1, 1e7]\n",
                                          "case 0001 (shear_rate = 1e+07): physics.shear_rate"),
    # session 33
    "a sweep given as a table of values": ("{head}[sweep]\nshear_rate = {{ values = [1.0, 2.0] }}\n",
                                           "sweep.shear_rate = {'values': [1.0, 2.0]}: use a list"),
    "a refinement over one axis": ("{head}[sweep]\nshear_rate = [1.0, 2.0]\npsi_bar = [0.3, 0.5]\n[refine]\n"
                                   'axes = ["shear_rate"]\n', "give the two swept parameters of the plane"),
    "a search and a refinement": ("{head}[sweep]\npsi_bar = [0.3, 0.5]\n[search]\n[refine]\n",
                                  "[search] and [refine] are two kinds of campaign: give one"),
    "a chain along an unswept key": ('{head}[sweep]\nshear_rate = [1.0, 2.0]\n[chain]\nalong = "B2"\n',
                                     "chain.along = 'B2': must name a swept key"),
    "an empty [starts]": ("{head}[sweep]\nshear_rate = [1.0, 2.0]\n[starts]\n", "[starts] names no start"),
    "a negative pattern_tol": ("{head}[sweep]\nshear_rate = [1.0, 2.0]\n[analysis]\npattern_tol = -1.0\n",
                               "analysis.pattern_tol = -1.0: must be > 0"),
    "min_resize_tail with a fixed N": ("{head}[sweep]\nshear_rate = [1.0, 2.0]\npsi_bar = [0.3, 0.5]\n[refine]\n"
                                       "min_resize_tail = 1e-6\n", 'only a run with numerics.N = "auto"'),
    "a refine budget of 0": ("{head}[sweep]\nshear_rate = [1.0, 2.0]\npsi_bar = [0.3, 0.5]\n[refine]\n"
                             "max_cases = 0\n", "refine.max_cases = 0: fewer than the 4 points"),
    "a swept psi_bar past 1": ("{head}[sweep]\npsi_bar = [0.3, 1.5]\n", "case 0001 (psi_bar = 1.5)"),
    "a NaN in a sweep": ("{head}[sweep]\nshear_rate = [1.0, nan]\n", "physics.shear_rate = nan: must be a finite"),
}


def invoke(*args):
    result = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=True)
    assert result.exception is None or isinstance(result.exception, SystemExit), \
        f"{type(result.exception).__name__}: {result.exception}"
    return result


def refused(result):
    """One ``Error:`` line, the last on stderr (progress lines may come before it), and exit status 2."""
    assert result.exit_code == 2, (result.exit_code, result.stdout, result.stderr)
    assert "Traceback" not in result.stderr and "Traceback" not in result.stdout
    lines = [line for line in result.stderr.strip().splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("Error: ")]
    assert len(errors) == 1 and lines[-1] == errors[0], result.stderr
    return errors[0]


def write(path, content):
    (path.write_bytes if isinstance(content, bytes) else path.write_text)(content)
    return path


@pytest.mark.parametrize("name", list(CASE_FILES))
def test_a_bad_case_file(tmp_path, name):
    content, words = CASE_FILES[name]
    line = refused(invoke("run", write(tmp_path / "case.toml", content), "--out", tmp_path / "out.h5"))
    assert words in line, line
    assert os.listdir(tmp_path) == ["case.toml"]


@pytest.mark.parametrize("name", list(STUDY_FILES))
def test_a_bad_study_file(tmp_path, name):
    content, words = STUDY_FILES[name]
    if isinstance(content, str):
        content = content.replace("{head}", STUDY_HEAD).replace("{{", "{").replace("}}", "}")
    line = refused(invoke("campaign", write(tmp_path / "study.toml", content), "--out", tmp_path / "out.h5"))
    assert words in line, line
    assert os.listdir(tmp_path) == ["study.toml"]


def error_lines(command, path, tmp_path):
    """The stderr lines of ``hpcves command path --out ...``, refused with exit status 2 and no traceback."""
    result = invoke(command, path, "--out", tmp_path / "out.h5")
    assert result.exit_code == 2 and "Traceback" not in result.stderr, result.stderr
    return [line for line in result.stderr.splitlines() if line.strip()]


def test_every_problem_of_a_case_file_is_told_at_once(tmp_path):
    # an unknown table, an unknown key and two bad types in two tables, a range in a third:
    # one Error line each, all naming the file
    content = ("[physic]\nx = 1\n[physics]\nshear = 3\npsi_bar = 'a'\n[numerics]\nN = 64.5\n"
               "[run]\nt_end = -1.0\n")
    path = write(tmp_path / "case.toml", content)
    errors = error_lines("run", path, tmp_path)
    assert errors == [f"Error: {path}: {problem}" for problem in (
        "unknown table: [physic] (did you mean [physics]?) (known: [physics], [numerics], [run]; "
        "and preset = \"publication\")",
        "[physics]: unknown key shear (did you mean shear_rate?) (known: " + errors[1].split("(known: ")[1][:-1] + ")",
        "physics.psi_bar = 'a': must be a number",
        "numerics.N = 64.5: must be an integer",
        "run.t_end = -1.0: must be > 0")], errors
    assert os.listdir(tmp_path) == ["case.toml"]


def test_every_problem_of_a_study_file_is_told_at_once(tmp_path):
    content = ("[campaign]\nname = ''\nstop_timeout = -1.0\nspeed = 2\n[physics]\npsi_bar = 2.0\n"
               "[analysis]\nwhatever = 1\n[sweep]\nshear_rate = [1.0, 'x']\nN = [32]\n")
    path = write(tmp_path / "study.toml", content)
    errors = error_lines("campaign", path, tmp_path)
    assert all(line.startswith(f"Error: {path}: ") for line in errors), errors
    for words in ("[campaign]: unknown key speed", "base case: physics.psi_bar = 2.0: must lie in [0, 1]",
                  "campaign.name = '': must be a non-empty string", "campaign.stop_timeout = -1.0: must be > 0",
                  "[analysis]: unknown key whatever", "sweep over N: only"):
        assert sum(words in line for line in errors) == 1, (words, errors)
    assert len(errors) == 6, errors


# ---------------------------------------------------------------------- damaged files
@pytest.fixture(scope="module")
def sound(tmp_path_factory):
    """A finished four-case campaign (study file, file) and a finished single-run file."""
    directory = tmp_path_factory.mktemp("sound")
    study_file = directory / "study.toml"
    study_file.write_text(STUDY_HEAD + "[sweep]\nshear_rate = [40, 80]\npsi_bar = [0.3, 0.5]\n")
    campaign = directory / "campaign.h5"
    assert run_campaign(study_from_toml(study_file.read_text()), campaign).exit_status == 0
    single = directory / "single.h5"
    with h5py.File(single, "w") as h5:
        runner.run(CaseStore.create(h5, case_from_toml(BASE_RUN)), h5.flush)
    return study_file, campaign, single


def older_layout(sound, tmp_path_factory, version, holds):
    """The campaign of ``sound`` as an older hpcves wrote it (campaign format ``version``), which holds
    ``holds``."""
    study_file, _, single = sound
    campaign = tmp_path_factory.mktemp(f"sound_v{version}") / "campaign.h5"
    with writing_format(version):
        assert run_campaign(study_from_toml(study_file.read_text()), campaign).exit_status == 0
    with h5py.File(campaign, "r") as f:
        assert f.attrs["format_version"] == version and holds in f
    return study_file, campaign, single


@pytest.fixture(scope="module")
def sound_v1(sound, tmp_path_factory):
    """Format 1: a group per case."""
    return older_layout(sound, tmp_path_factory, 1, "cases")


@pytest.fixture(scope="module")
def sound_v2(sound, tmp_path_factory):
    """Format 2: blocks, a dataset a record."""
    return older_layout(sound, tmp_path_factory, 2, "blocks/0/timeseries/theta")


def header_of(f, name):
    return h5py.h5o.get_info(f[name].id).addr


def flip(name, mask=0x40):
    """Damage: flip a bit in the first byte of ``name``'s object header (HDF5 cannot open it any more)."""
    def damage(path):
        with h5py.File(path, "r") as f:
            address = header_of(f, name)
        with open(path, "r+b") as f:
            f.seek(address)
            byte = f.read(1)[0]
            f.seek(address)
            f.write(bytes([byte ^ mask]))
    return damage


def edit(change):
    def damage(path):
        with h5py.File(path, "r+") as f:
            change(f)
    return damage


def replace_bytes(make):
    def damage(path):
        data = path.read_bytes()
        path.unlink()
        content = make(data)
        if content is None:
            path.mkdir()
        else:
            path.write_bytes(content)
    return damage


def recreate(name, **kwargs):
    def change(f):
        del f[name]
        parent, _, leaf = name.rpartition("/")
        f[parent].create_dataset(leaf, **kwargs)
    return change


def set_value(name, value):
    def change(f):
        f[name][...] = value
    return change


def set_case(case_id, name, value):
    """Damage: write ``value`` to case ``case_id``'s array ``name`` (either layout)."""
    def change(f):
        case_view(f, case_id)[name] = value
    return change


def set_config(case_id, text):
    """Damage: a case's stored config text (format 2: its row of index/config) set to ``text`` (a
    callable of the file gives it)."""
    def change(f):
        i = [v.decode() for v in f["index/case_id"][:]].index(case_id)
        f["index/config"][i] = text(f) if callable(text) else text
    return change


def symlink_loop(path):
    path.unlink()
    os.symlink(path.name, path)


#: damaged campaign files: damage -> (words, commands that must refuse it)
ALL = ("status", "analyze", "resume")
N_QUANTITIES = len(QUANTITIES)
CAMPAIGN_DAMAGE = {
    "random bytes": (replace_bytes(lambda d: np.random.default_rng(1).bytes(4096)), "not a readable HDF5", ALL),
    "zeros": (replace_bytes(lambda d: bytes(len(d))), "not a readable HDF5", ALL),
    "empty": (replace_bytes(lambda d: b""), "empty (0 bytes), not an HDF5 file", ALL),
    "truncated to a tenth": (replace_bytes(lambda d: d[:len(d) // 10]), "", ALL),
    "truncated to half": (replace_bytes(lambda d: d[:len(d) // 2]), "", ALL),
    "truncated at the end": (replace_bytes(lambda d: d[:len(d) - 1000]), "", ALL),
    "a directory": (replace_bytes(lambda d: None), "is a directory", ALL),
    "a symlink loop": (symlink_loop, "", ALL),
    "no format": (edit(lambda f: f.attrs.__delitem__("format")), "not an hpcves", ALL),
    "another format version": (edit(lambda f: f.attrs.__setitem__("format_version", 99)), "format version 99", ALL),
    "no index": (edit(lambda f: f.__delitem__("index")), "missing index", ALL),
    "case count wrong": (edit(lambda f: f.attrs.__setitem__("n_cases", 9)), "holds 4 cases, its header says 9", ALL),
    "another study": (edit(lambda f: f.attrs.__setitem__("name", "other")), "belongs to study 'other'", ("resume",)),
    "a short index": (edit(recreate("index/shear_rate", data=np.array([40.0]))), "", ALL),
    "unknown status": (edit(set_case("0003", "status", 77)), "status 77 is not a status", ALL),
    "samples beyond capacity": (edit(set_case("0000", "timeseries/length", 10_000)), "lies outside", ALL),
    "negative snapshot count": (edit(set_case("0000", "snapshots/length", -1)), "lies outside", ALL),
    "validity marker 5": (edit(set_case("0001", "checkpoint/slot0/meta", [5, 1, 1, 1])), "neither 0 nor 1", ALL),
    "checkpoint beyond the end": (edit(set_case("0001", "checkpoint/slot0/meta", [1, 999, 1, 1])),
                                  "step 999 outside", ALL),
    "checkpoint against its series": (edit(set_case("0001", "checkpoint/slot0/meta", [1, 10, 7, 1])),
                                      "before step 10", ALL),
    "finished, half the samples": (edit(set_case("0003", "timeseries/length", 2)), "finished, but holds", ALL),
    "no blocks": (edit(lambda f: f.__delitem__("blocks")), "missing blocks", ALL),
    "no status in the block": (edit(lambda f: f.__delitem__("blocks/0/status")), "0000", ALL),
    "no series in the block": (edit(lambda f: f.__delitem__("blocks/0/timeseries/series")),
                               "timeseries/series is missing", ALL),
    "series of the wrong length": (edit(recreate("blocks/0/timeseries/series", data=np.zeros((4, 3, N_QUANTITIES)))),
                                   f"timeseries/series has shape (3, {N_QUANTITIES})", ALL),
    "a quantity short": (edit(recreate("blocks/0/timeseries/series", data=np.zeros((4, 6, N_QUANTITIES - 1)))),
                         f"expected (6, {N_QUANTITIES})", ALL),
    "snapshot fields of the wrong width": (edit(recreate("blocks/0/snapshots/fields", data=np.zeros((4, 5, 7, 33)))),
                                           "snapshots/fields has shape (5, 7, 33)", ALL),
    "checkpoint of the wrong size": (edit(recreate("blocks/0/checkpoint/slot1/arrays", data=np.zeros((4, 8, 33)))),
                                     "checkpoint/slot1/arrays has shape (8, 33)", ALL),
    "a checkpoint array short": (edit(recreate("blocks/0/checkpoint/slot0/arrays", data=np.zeros((4, 7, 32)))),
                                 "checkpoint/slot0/arrays has shape (7, 32)", ALL),
    "scalars of the wrong type": (edit(recreate("blocks/0/checkpoint/slot0/scalars", data=np.zeros((4, 10), "i4"))),
                                  "checkpoint/slot0/scalars has shape", ALL),
    "a block with fewer rows": (edit(recreate("blocks/0/progress", data=np.zeros((2, 4)))), "0002", ALL),
    "a block of another format version": (edit(lambda f: f["blocks/0"].attrs.__setitem__("format_version", 99)),
                                          "format version 99", ALL),
    "a block without its shape": (edit(lambda f: f["blocks/0"].attrs.__delitem__("shape")), "block 0", ALL),
    "a row outside its block": (edit(set_value("index/row", [0, 99, 2, 3])), "row 99 lies outside", ALL),
    "an unknown block": (edit(set_value("index/block", [0, 7, 0, 0])), "block 7 is missing", ALL),
    "a negative row": (edit(set_value("index/row", [0, 1, -2, 3])), "row -2 lies outside", ALL),
    "no config column": (edit(lambda f: f.__delitem__("index/config")), "index/config is missing", ALL),
    "a short block column": (edit(recreate("index/block", data=np.zeros(2, "i4"))), "index/block is missing", ALL),
    "config not TOML": (edit(set_config("0000", "[numerics\n")), "config attribute cannot be read", ALL),
    "config empty": (edit(set_config("0002", "")), "0002", ALL),
    "config of another case": (edit(set_config("0000", lambda f: f["index/config"][1])),
                               "config differs from its study's case", ("resume",)),
    "header of the block's status flipped": (flip("blocks/0/status"), "", ALL),
    "header of the block's series flipped": (flip("blocks/0/timeseries/series"), "0000", ALL),
    "header of the block's snapshot fields flipped": (flip("blocks/0/snapshots/fields"), "0000", ALL),
    "header of the block's checkpoint flipped": (flip("blocks/0/checkpoint/slot1/meta"), "0000", ALL),
    "header of the block's checkpoint arrays flipped": (flip("blocks/0/checkpoint/slot0/arrays"), "0000", ALL),
    "header of a block group flipped": (flip("blocks/0"), "", ALL),
    "header of the config column flipped": (flip("index/config"), "", ALL),
    "format version 1.5": (edit(lambda f: f.attrs.__setitem__("format_version", 1.5)), "format version 1.5", ALL),
    "format version a string": (edit(lambda f: f.attrs.__setitem__("format_version", "1")), "format version '1',",
                                ALL),
    "an unknown mode": (edit(lambda f: f.attrs.__setitem__("mode", "bogus")), "mode 'bogus' is not a kind", ALL),
    "case count 4.5": (edit(lambda f: f.attrs.__setitem__("n_cases", 4.5)), "case count 4.5 is not a count", ALL),
    "header of the index flipped": (flip("index/case_id"), "", ALL),
}
#: damage to files of campaign format 2 (blocks with a dataset a record)
CAMPAIGN_V2_DAMAGE = {
    "unknown status": (edit(set_case("0003", "status", 77)), "status 77 is not a status", ALL),
    "finished, half the samples": (edit(set_case("0003", "timeseries/length", 2)), "finished, but holds", ALL),
    "no theta in the block": (edit(lambda f: f.__delitem__("blocks/0/timeseries/theta")),
                              "timeseries/theta is missing", ALL),
    "theta of the wrong size": (edit(recreate("blocks/0/timeseries/theta", data=np.zeros((4, 3)))), "shape (3,)", ALL),
    "checkpoint of the wrong size": (edit(recreate("blocks/0/checkpoint/slot1/psi", data=np.zeros((4, 33)))),
                                     "checkpoint/slot1/psi has shape (33,)", ALL),
    "header of the block's series flipped": (flip("blocks/0/timeseries/theta"), "0000", ALL),
    "a block of another format version": (edit(lambda f: f["blocks/0"].attrs.__setitem__("format_version", 99)),
                                          "format version 99", ALL),
}
#: damage to files of the older layout (a group per case)
CAMPAIGN_V1_DAMAGE = {
    "no cases": (edit(lambda f: f.__delitem__("cases")), "missing cases", ALL),
    "case count wrong": (edit(lambda f: f.attrs.__setitem__("n_cases", 9)), "holds 4 cases, its header says 9", ALL),
    "unknown status": (edit(set_case("0003", "status", 77)), "status 77 is not a status", ALL),
    "config of another case": (edit(lambda f: f["cases/0000"].attrs.__setitem__("config", f["cases/0001"].attrs[
        "config"])), "config differs from its study's case", ("resume",)),
    "no status": (edit(lambda f: f.__delitem__("cases/0002/status")), "0002", ALL),
    "no progress": (edit(lambda f: f.__delitem__("cases/0001/progress")), "0001", ALL),
    "no theta": (edit(lambda f: f.__delitem__("cases/0001/timeseries/theta")), "timeseries/theta is missing", ALL),
    "theta of the wrong size": (edit(recreate("cases/0001/timeseries/theta", data=np.zeros(3))), "shape (3,)", ALL),
    "checkpoint of the wrong size": (edit(recreate("cases/0002/checkpoint/slot1/psi", data=np.zeros(33))),
                                     "checkpoint/slot1/psi has shape (33,)", ALL),
    "scalars of the wrong type": (edit(recreate("cases/0002/checkpoint/slot0/scalars", data=np.zeros(10, "i4"))),
                                  "checkpoint/slot0/scalars has shape", ALL),
    "samples beyond capacity": (edit(set_value("cases/0000/timeseries/length", 10_000)), "lies outside", ALL),
    "negative snapshot count": (edit(set_value("cases/0000/snapshots/length", -1)), "lies outside", ALL),
    "validity marker 5": (edit(set_value("cases/0001/checkpoint/slot0/meta", [5, 1, 1, 1])), "neither 0 nor 1", ALL),
    "checkpoint beyond the end": (edit(set_value("cases/0001/checkpoint/slot0/meta", [1, 999, 1, 1])),
                                  "step 999 outside", ALL),
    "checkpoint against its series": (edit(set_value("cases/0001/checkpoint/slot0/meta", [1, 10, 7, 1])),
                                      "before step 10", ALL),
    "finished, half the samples": (edit(set_value("cases/0003/timeseries/length", 2)), "finished, but holds", ALL),
    "config not TOML": (edit(lambda f: f["cases/0000"].attrs.__setitem__("config", "[numerics\n")),
                        "config attribute cannot be read", ALL),
    "header of a status flipped": (flip("cases/0001/status"), "0001", ALL),
    "header of a series flipped": (flip("cases/0002/timeseries/theta"), "0002", ALL),
    "header of a checkpoint flipped": (flip("cases/0003/checkpoint/slot1/meta"), "0003", ALL),
    "header of a case group flipped": (flip("cases/0000"), "0000", ALL),
}


def damaged(sound, tmp_path, name, table=CAMPAIGN_DAMAGE):
    study_file, campaign, _ = sound
    copy = tmp_path / "damaged.h5"
    copy.write_bytes(campaign.read_bytes())
    table[name][0](copy)
    return study_file, copy


@pytest.mark.parametrize("layout, name", [(3, name) for name in CAMPAIGN_DAMAGE]
                         + [(2, name) for name in CAMPAIGN_V2_DAMAGE] + [(1, name) for name in CAMPAIGN_V1_DAMAGE])
def test_a_damaged_campaign_file(sound, sound_v2, sound_v1, tmp_path, layout, name):
    table = {3: CAMPAIGN_DAMAGE, 2: CAMPAIGN_V2_DAMAGE, 1: CAMPAIGN_V1_DAMAGE}[layout]
    study_file, copy = damaged({3: sound, 2: sound_v2, 1: sound_v1}[layout], tmp_path, name, table)
    _, words, commands = table[name]
    calls = {"status": ("status", "--check", copy),
             "analyze": ("analyze", copy, "--out", tmp_path / "a", "--no-case-figures", "--no-write-back"),
             "resume": ("campaign", study_file, "--resume", "--out", copy, "--quiet")}
    for command in commands:
        line = refused(invoke(*calls[command]))
        assert words in line, (command, line)


#: damaged single-run files: damage -> words; refused by ``run --resume`` and ``analyze``
CASE_DAMAGE = {
    "random bytes": (replace_bytes(lambda d: np.random.default_rng(2).bytes(2048)), "not a readable HDF5"),
    "truncated": (replace_bytes(lambda d: d[:len(d) // 3]), ""),
    "a campaign file": (None, "a campaign file, not a case's: `hpcves campaign STUDY.toml --resume`"),  # (analyze
                                                                      # reads it, as it should)
    "no format": (edit(lambda f: f.attrs.__delitem__("format")), "not an hpcves"),
    "version 1": (edit(lambda f: f.attrs.__setitem__("format_version", 1)), "case format version 1"),
    "version 4.5": (edit(lambda f: f.attrs.__setitem__("format_version", 4.5)), "case format version 4.5"),
    "no timeseries": (edit(lambda f: f.__delitem__("timeseries")), "incomplete case, missing timeseries"),
    "unknown status": (edit(set_value("status", 9)), "status 9 is not a status"),
    "series of the wrong size": (edit(recreate("timeseries/E_bending", data=np.zeros(5))), "shape (5,)"),
    "counter beyond capacity": (edit(set_value("snapshots/length", 999)), "lies outside"),
    "checkpoint against its series": (edit(set_value("checkpoint/slot1/meta", [1, 10, 9, 9])), "before step 10"),
    "config not TOML": (edit(lambda f: f.attrs.__setitem__("config", "x = ")), "config attribute cannot be read"),
    "header of a series flipped": (flip("timeseries/theta"), "timeseries/theta"),
}


@pytest.mark.parametrize("name", list(CASE_DAMAGE))
def test_a_damaged_run_file(sound, tmp_path, name):
    _, campaign, single = sound
    copy = tmp_path / "damaged.h5"
    damage, words = CASE_DAMAGE[name]
    copy.write_bytes((campaign if damage is None else single).read_bytes())
    if damage is not None:
        damage(copy)
    calls = [("run", "--resume", copy), ("analyze", copy, "--out", tmp_path / "a", "--no-case-figures")]
    for args in calls[:1] if damage is None else calls:
        line = refused(invoke(*args))
        assert words in line, (args, line)


def test_the_corpus_holds_over_a_hundred_inputs():
    assert len(CASE_FILES) + len(STUDY_FILES) + len(CAMPAIGN_DAMAGE) + len(CAMPAIGN_V1_DAMAGE) + len(CASE_DAMAGE) >= 100


# ---------------------------------------------------------------------- paths that are not plain files
def test_devices_pipes_and_empty_files_are_refused_and_left_untouched(sound, tmp_path):
    """/dev/null opened as HDF5 crashed h5py (exit 139), an empty file was given a superblock by
    HDF5 1.10's r+ open, and an empty study or /dev/null ran a default campaign: each is now one line."""
    study_file, campaign, _ = sound
    case_file = write(tmp_path / "case.toml", BASE_RUN)
    empty = write(tmp_path / "empty.h5", b"")
    pipe = tmp_path / "pipe"
    os.mkfifo(pipe)
    calls = {
        ("run", "--resume", os.devnull): "a character device, not a file",
        ("run", "--resume", empty): "empty (0 bytes), not an HDF5 file",
        ("run", os.devnull, "--out", tmp_path / "a.h5"): "a character device, not a TOML file",
        ("run", case_file, "--out", os.devnull): "a character device, not a file",
        ("run", pipe, "--out", tmp_path / "a.h5"): "a named pipe, not a TOML file",
        ("run", f"{case_file}/", "--out", tmp_path / "a.h5"): "ends in '/'",
        ("campaign", os.devnull, "--out", tmp_path / "c.h5"): "a character device, not a TOML file",
        ("campaign", f"{study_file}/", "--out", tmp_path / "c.h5"): "ends in '/'",
        ("campaign", study_file, "--out", os.devnull, "--quiet"): "a character device, not a file",
        ("campaign", study_file, "--resume", "--out", empty, "--quiet"): "empty (0 bytes)",
        ("status", os.devnull): "a character device, not a file",
        ("status", "--check", pipe): "a named pipe, not a file",
        ("status", empty): "empty (0 bytes)",
        ("analyze", os.devnull, "--out", tmp_path / "x"): "a character device, not a file",
        ("analyze", empty, "--out", tmp_path / "x"): "empty (0 bytes)",
    }
    for args, words in calls.items():
        line = refused(invoke(*args))
        assert words in line, (args, line)
    assert empty.stat().st_size == 0
    assert sorted(os.listdir(tmp_path)) == ["case.toml", "empty.h5", "pipe"]


def test_analyze_of_a_file_it_may_not_replace_writes_the_tables_and_says_why_it_kept_the_file(sound, tmp_path):
    """An immutable file (chattr +i) refused the rename of the analysed copy over it: exit 2 with
    '...partial: Operation not permitted', the copy left beside it. Now the documented note, exit 0."""
    import shutil
    import subprocess

    _, campaign, _ = sound
    copy = tmp_path / "immutable.h5"
    shutil.copyfile(campaign, copy)
    if shutil.which("chattr") is None or subprocess.run(["chattr", "+i", copy], capture_output=True).returncode:
        pytest.skip("chattr +i is not permitted here")
    try:
        result = invoke("analyze", copy, "--out", tmp_path / "tables", "--no-case-figures")
        assert result.exit_code == 0, result.stderr
        assert "results not written into the file: cannot replace it" in result.stderr, result.stderr
        assert "the file is unchanged" in result.stderr
        assert (tmp_path / "tables" / "regimes.csv").exists()
        assert not list(tmp_path.glob("*.partial"))
        assert copy.read_bytes() == campaign.read_bytes()
    finally:
        subprocess.run(["chattr", "-i", copy], check=False)


def test_a_plan_for_a_file_larger_than_the_free_disk_times_a_step_and_says_so(tmp_path, monkeypatch):
    """--plan timed a step by running the case into a scratch file as large as the whole case's; a
    study whose cases would not fit the disk stopped with a StorageError traceback, exit 1. (The
    disk here is made to have 1 GB free: the study's file needs 43 GB.)"""
    from hpcves.files import atomic

    monkeypatch.setattr(atomic, "free_bytes", lambda path: 10**9)
    study = write(tmp_path / "huge.toml", STUDY_HEAD.replace("t_end = 0.02\n", "t_end = 1e5\n", 1)
                  .replace("t_end = 0.02\nsample_interval", "t_end = 1e5\nsample_interval")
                  + "[sweep]\nshear_rate = [1, 2]\n")
    result = invoke("campaign", study, "--plan", "--out", tmp_path / "huge.h5")
    assert result.exit_code == 0 and "Traceback" not in result.stderr, result.stderr
    assert "not enough, the campaign would refuse to start" in result.stdout, result.stdout
    assert sorted(os.listdir(tmp_path)) == ["huge.toml"]


def test_a_byte_order_mark_is_read_past():
    """Some editors begin UTF-8 files with a byte-order mark, which TOML's parser took for a statement."""
    import tempfile
    from pathlib import Path

    from hpcves.config import load_case

    with tempfile.TemporaryDirectory() as d:
        plain, marked = Path(d) / "plain.toml", Path(d) / "marked.toml"
        plain.write_text("[physics]\nshear_rate = 7.0\n", encoding="utf-8")
        marked.write_text("\ufeff[physics]\nshear_rate = 7.0\n", encoding="utf-8")
        assert marked.read_bytes().startswith(b"\xef\xbb\xbf")
        assert load_case(marked) == load_case(plain) and load_case(marked).physics.shear_rate == 7.0


def test_links_and_missing_folders_are_refused_in_one_line(tmp_path):
    """Session 33: a dangling symlink as the case file, --out in a folder that does not exist, --out a link
    to a device: one line, exit 2, nothing written."""
    case = tmp_path / "ok.toml"
    case.write_text("[physics]\nshear_rate = 3.0\n")
    (tmp_path / "dangling.toml").symlink_to(tmp_path / "nowhere.toml")
    (tmp_path / "null.h5").symlink_to("/dev/null")
    before = sorted(os.listdir(tmp_path))
    for args, words in ((("run", tmp_path / "dangling.toml", "--out", tmp_path / "o.h5"),
                         "dangling.toml: no such file"),
                        (("run", case, "--out", tmp_path / "no" / "where" / "o.h5"), "cannot create it"),
                        (("run", case, "--out", tmp_path / "null.h5"), "a character device, not a file")):
        line = refused(invoke(*args))
        assert words in line, (args, line)
    assert sorted(os.listdir(tmp_path)) == before
