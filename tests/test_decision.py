"""Run until decided (decision.py): synthetic series, real TT and PT cases, resume, campaigns."""
import h5py
import numpy as np
import pytest

from hpcves.analysis.regimes import AnalysisSettings
from hpcves.config import case_from_toml
from hpcves.model.params import RunControl
from hpcves.reports.analyze import analyze
from hpcves.run import decision
from hpcves.run.store import FINISHED, INTERRUPTED, CaseStore, open_file
from jobs import MPIRUN, assert_same_results, hpcves, resume_in_process, run_in_process, same_case_files

RULES = RunControl(until_decided=True, decided_shear_times=50.0, decided_periods=5.0)


def series(t, theta, lab_speed=0.0):
    n = t.size
    return {"t": t, "theta": theta, "V_psi": np.full(n, lab_speed), "V_L": np.zeros(n),
            "tank_treading_velocity": np.ones(n), "psi_min": np.zeros(n), "psi_max": np.ones(n)}


def test_tank_treading_is_decided_once_steady_for_the_stated_shear_times():
    S = 10.0
    t = np.arange(0, 8.0, 0.01)
    theta = 0.6 + 0.2 * np.exp(-t / 0.3)                 # settles (within 1e-4) by t ~ 2.3
    for end, decided in ((5.0, False), (7.9, True)):     # steady for ~27, then ~56 shear times
        keep = t <= end
        found = decision.decide(series(t[keep], theta[keep]), S, RULES)
        assert (found is not None) == decided, (end, found)
    assert found.regime == "TT" and "shear times" in found.reason


def test_phase_treading_is_decided_after_the_stated_periods_and_tumbling_likewise():
    t = np.arange(0, 3.0, 0.002)
    period = 0.2
    pt = 0.5 + 0.05 * np.sin(2 * np.pi * t / period)
    assert decision.decide(series(t[t <= 0.7], pt[t <= 0.7], lab_speed=0.5), 80.0, RULES) is None   # 3 periods
    found = decision.decide(series(t, pt, lab_speed=0.5), 80.0, RULES)
    assert found.regime == "PT" and "settled periods" in found.reason
    tu = 0.5 * np.sin(2 * np.pi * t / period)
    assert decision.decide(series(t, tu, lab_speed=0.5), 80.0, RULES).regime == "TU"


def test_undecided_and_short_series_never_stop_a_case():
    t = np.arange(0, 3.0, 0.002)
    drifting = 0.5 + 0.1 * t                              # never settles
    assert decision.decide(series(t, drifting), 80.0, RULES) is None
    assert decision.decide(series(t[:20], np.full(20, 0.6)), 80.0, RULES) is None
    steady_but_moving = np.full(t.size, 0.6)              # theta steady, the pattern moving: undecided
    assert decision.decide(series(t, steady_but_moving, lab_speed=0.5), 80.0, RULES) is None


#: numerics and run settings of the real cases here (a TOML tail, [run] last so that more keys can follow)
DECIDING = """[numerics]
N = 32
rtol = 1e-2
[run]
max_spectral_tail = 1.0          # N = 32 on purpose (fast): the resolution watch would stop it
sample_interval = 0.005
snapshot_interval = 0.5
checkpoint_interval = 0.25
checkpoint_wall = 0
until_decided = true
decided_shear_times = 30
decided_periods = 5
decision_samples = 20
"""

UNTIL = """
[physics]
shear_rate = {S}
psi_bar = {psi_bar}
""" + DECIDING + "t_end = 20.0\n"


@pytest.mark.parametrize("S, psi_bar, regime", [(10.0, 0.0, "TT"), (80.0, 0.3, "PT")])
def test_a_real_case_stops_when_decided_and_analyze_agrees(tmp_path, S, psi_bar, regime):
    case = case_from_toml(UNTIL.format(S=S, psi_bar=psi_bar))
    outcome = run_in_process(case, tmp_path / "a.h5")
    assert outcome.status == FINISHED and outcome.message.startswith(f"decided {regime}"), outcome.message
    assert outcome.t < 0.5 * case.run.t_end
    with open_file(tmp_path / "a.h5", "r") as f:
        store = CaseStore.open(f)
        assert store.problems() == []
        code, t, step = store.decision
        assert decision.REGIMES_BY_CODE[code] == regime and t == outcome.t
    rows = analyze(tmp_path / "a.h5", tmp_path / "out", case_figures=False).rows
    assert rows[0]["regime"] == regime and "stopped when decided" in rows[0]["reason"]


def test_a_resumed_case_reaches_the_same_decision_at_the_same_step(tmp_path):
    case = case_from_toml(UNTIL.format(S=80.0, psi_bar=0.3))
    assert run_in_process(case, tmp_path / "a.h5").status == FINISHED
    assert run_in_process(case, tmp_path / "b.h5", max_steps=400).status == INTERRUPTED
    assert resume_in_process(tmp_path / "b.h5", stops=(350, None)).status == FINISHED
    same_case_files(tmp_path / "a.h5", tmp_path / "b.h5")
    with h5py.File(tmp_path / "a.h5", "r") as fa, h5py.File(tmp_path / "b.h5", "r") as fb:
        assert np.array_equal(fa["decision"][:], fb["decision"][:])
        assert bytes(fa["message"][()]) == bytes(fb["message"][()])


def test_decision_rules_are_validated_and_left_out_of_old_fingerprints():
    with pytest.raises(Exception, match="decided_periods"):
        case_from_toml("[run]\nuntil_decided = true\ndecided_periods = 0.5\n")
    plain = case_from_toml("[run]\nt_end = 2.0\n")
    assert "until_decided" not in plain.significant()["run"]
    assert case_from_toml("[run]\nuntil_decided = true\n").significant()["run"]["until_decided"] is True


def test_the_study_thresholds_decide():
    t = np.arange(0, 3.0, 0.002)
    pt = 0.5 + 0.05 * np.sin(2 * np.pi * t / 0.2)
    strict = AnalysisSettings(pattern_tol=0.9)            # a pattern at 0.5 of V is "fixed" for these
    assert decision.decide(series(t, pt, lab_speed=0.5), 80.0, RULES, strict) is None
    assert decision.decide(series(t, pt, lab_speed=0.5), 80.0, RULES).regime == "PT"


CAMPAIGN = """
[campaign]
name = "decided"
output = "{output}"
t_end = 6.0
""" + DECIDING + """[sweep]
shear_rate = [10, 80]
psi_bar = [0.0, 0.3]
"""


@pytest.fixture(scope="module")
def decided_reference(tmp_path_factory):
    from hpcves.campaign.driver import run_campaign
    from hpcves.campaign.study import study_from_toml

    directory = tmp_path_factory.mktemp("decided")
    output = directory / "reference.h5"
    summary = run_campaign(study_from_toml(CAMPAIGN.format(output=output)), output)
    assert summary.exit_status == 0
    return output


def test_a_campaign_runs_its_cases_until_decided(decided_reference):
    from hpcves.reports.analyze import read_source

    source = read_source(decided_reference)
    messages = {c.case_id: c.message for c in source.cases}
    assert all(m.startswith("decided") for m in messages.values()), messages
    assert all(c.t < 6.0 for c in source.cases)


@pytest.mark.skipif(MPIRUN is None, reason="no mpirun")
@pytest.mark.parametrize("io", ["mpio", "relay"])
def test_an_mpi_campaign_until_decided_matches_the_serial_one(tmp_path, decided_reference, io):
    output = tmp_path / "decided.h5"
    study = tmp_path / "decided.toml"
    study.write_text(CAMPAIGN.format(output=output))
    result = hpcves("campaign", study, "--quiet", "--io", io, n=2)
    assert result.returncode == 0, result.stderr
    assert_same_results(decided_reference, output, attrs=False)
