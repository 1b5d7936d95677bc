"""Kills at scale (``make faults``): in the middle of laying out 5000 cases, and in a refinement's
bookkeeping between stages of hundreds of cases; each resumed to the file an uninterrupted run makes,
bit for bit. Tiny cases (N = 16, 10 steps), so that the cases are many and the run short."""
import pytest

from jobs import MPIRUN, TEN_STEPS, assert_same_results, hpcves, mpi_env

pytestmark = [pytest.mark.faults, pytest.mark.skipif(MPIRUN is None, reason="no mpirun")]

GRID = """[campaign]
name = "bulk"
output = "{output}"
""" + TEN_STEPS + """[sweep]
shear_rate = {{ linspace = [1, 100, 5000] }}
"""
# every point is undecided after 10 steps, so each refinement splits its cells to the tolerance:
# stages of 8, 12, ... up to hundreds of cases
REFINE = """[campaign]
name = "stages"
output = "{output}"
""" + TEN_STEPS + """[sweep]
shear_rate = [1.0, 100.0]
psi_bar = [0.0, 0.8]
B2 = [0.1, 0.2]
[refine]
tolerance = { shear_rate = 0.05, psi_bar = 0.05 }
max_cases = 300
"""


def study(directory, text):
    directory.mkdir(parents=True, exist_ok=True)
    output = directory / "c.h5"
    path = directory / "c.toml"
    path.write_text(text.replace("{output}", str(output)).replace("{{", "{").replace("}}", "}"))
    return path, output


@pytest.fixture(scope="module")
def references(tmp_path_factory):
    made = {}

    def get(text):
        if text not in made:
            path, output = study(tmp_path_factory.mktemp("reference"), text)
            result = hpcves("campaign", path, "--quiet", n=2, timeout=3600)
            assert result.returncode == 0, result.stderr
            made[text] = output
        return made[text]
    return get


def killed_and_resumed(tmp_path, text, fault, io, n=2):
    path, output = study(tmp_path / "job", text)
    killed = hpcves("campaign", path, "--quiet", "--io", io, n=n, env=mpi_env(HPCVES_FAULT=fault), timeout=3600)
    assert killed.returncode != 0, "the fault point was never reached"
    resumed = hpcves("campaign", path, "--quiet", "--io", io, "--resume", n=n, timeout=3600)
    assert resumed.returncode == 0, resumed.stderr
    return output


@pytest.mark.parametrize("io", ["mpio", "relay"])
def test_a_kill_while_5000_cases_are_laid_out_resumes_bitwise(tmp_path, references, io):
    output = killed_and_resumed(tmp_path, GRID, "block-grown:15@0", io)
    assert_same_results(output, references(GRID))


@pytest.mark.parametrize("fault, io", [
    ("verdicts-stored:3@0", "mpio"),       # just after the third stage's verdicts were written in place
    ("block-grown:50@0", "relay"),         # rank 0 growing the block by a later stage's cases in the copy
                                           # (21 arrays a stage)
    ("publish:4@0", "mpio"),               # a stage's copy complete, killed before it replaces the file
])
def test_a_kill_in_the_bookkeeping_between_stages_resumes_bitwise(tmp_path, references, fault, io):
    output = killed_and_resumed(tmp_path, REFINE, fault, io)
    assert_same_results(output, references(REFINE))
