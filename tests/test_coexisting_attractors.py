"""Several attractors at one parameter point (SPEC section 7): the publication's Fig. 9 case, Delta = 2.3,
psi_bar = 0.48, S = 28, reaches two stable states from different starts -- from the ellipse with the
published perturbation the soft phase gathers on both tips and the vesicle tank-treads; from the authors'
smoothed start, or from the ellipse with one soft domain laid down beyond the spinodal range (psi_bar +-
0.3), one domain travels from tip to tip (phase-treading)."""
import pytest

from hpcves.analysis.pattern import soft_domains
from hpcves.config import case_from_toml
from hpcves.run.store import FINISHED, CaseStore, open_file
from jobs import run_in_process

FIG9 = """
[physics]
excess_length = 2.3
psi_bar = 0.48
shear_rate = 28.0
initial_shape = "{shape}"
{phase}
[numerics]
N = 128
rtol = 1e-3
[run]
t_end = 6.0
until_decided = true
decided_shear_times = 30
decided_periods = 5
sample_interval = 0.0035
snapshot_interval = 0.05
checkpoint_interval = 6.0
"""


def _settle(tmp_path, name: str, shape: str, phase: str = "") -> tuple[str, set]:
    """Run a start until decided: (the decision, the soft-domain counts over the second half)."""
    path = tmp_path / f"{name}.h5"
    outcome = run_in_process(case_from_toml(FIG9.format(shape=shape, phase=phase)), path)
    assert outcome.status == FINISHED, outcome.message
    with open_file(path, "r") as f:
        snapshots = CaseStore.open(f).snapshots()
    settled = snapshots["psi"][snapshots["t"] >= 0.5 * outcome.t]
    return outcome.message.split(":")[0], {len(soft_domains(psi)) for psi in settled}


def test_the_fig9_point_reaches_two_attractors_from_two_starts(tmp_path):
    regime, domains = _settle(tmp_path, "ellipse", "ellipse")
    assert regime.startswith("decided TT") and domains == {2}
    regime, domains = _settle(tmp_path, "smoothed", "smoothed")
    assert regime.startswith("decided PT") and domains == {1}


@pytest.mark.slow
def test_one_domain_on_the_ellipse_reaches_the_phase_treading_attractor_too(tmp_path):
    regime, domains = _settle(tmp_path, "one domain", "ellipse", 'initial_phase = "domains"\nphase_domains = 1\n'
                              'delta = 0.3')
    assert regime.startswith("decided PT") and domains == {1}
