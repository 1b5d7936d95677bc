"""Continuation: a start carried over from another state, chains of cases along one swept key
([chain]), their scheduling, and a chain killed with SIGKILL then resumed bitwise like one run
without a stop."""

import dataclasses

import h5py
import numpy as np
import pytest

from hpcves.campaign.driver import run_campaign
from hpcves.campaign.queue import WorkQueue
from hpcves.campaign.study import study_from_toml
from hpcves.model import continuation, geometry
from hpcves.model.params import Case, ConfigError, Numerics, Physics, RunControl
from hpcves.numerics.spectral import resample
from hpcves.run import runner
from hpcves.run.store import FAILED, FINISHED, MODEL_LIMIT, PENDING
from hpcves.solver.timestepping import Solver
from jobs import (
    MPIRUN,
    assert_same_results,
    case_statuses,
    case_store,
    freeze_when,
    hpcves,
    kill_job,
    running_cases,
    start_job,
)

needs_mpi = pytest.mark.skipif(MPIRUN is None, reason="no mpirun")

CHAIN = """
[campaign]
name = "chain"
output = "{output}"
t_end = {t_end}
[numerics]
N = 32
dt = 1e-3
[run]
max_spectral_tail = 1.0          # N = 32 on purpose (fast)
sample_interval = 0.005
snapshot_interval = 0.05
checkpoint_interval = 0.02
checkpoint_wall = 0
[sweep]
psi_bar = [0.3, 0.5]
shear_rate = [10, 20, 40]
[chain]
along = "shear_rate"
back = true
"""


def write_chain(tmp_path, t_end=0.2, name="chain", until_decided=False):
    output = tmp_path / f"{name}.h5"
    path = tmp_path / f"{name}.toml"
    text = CHAIN.format(output=output, t_end=t_end)
    path.write_text(text.replace("[run]\n", "[run]\nuntil_decided = true\n") if until_decided else text)
    return path, output


@pytest.fixture(scope="module")
def decided_chain(tmp_path_factory):
    """The chain study run serially until each case is decided (t_end = 3 at most): (study, file)."""
    path, output = write_chain(tmp_path_factory.mktemp("decided"), t_end=3.0, until_decided=True)
    study = study_from_toml(path.read_text())
    assert run_campaign(study, output).exit_status == 0
    return study, output


# ---------------------------------------------------------------------- the carried start
def solver(excess_length=2.3, psi_bar=0.48, N=64, **kwargs):
    return Solver(Case(Physics(shear_rate=5.0, psi_bar=psi_bar, excess_length=excess_length),
                       Numerics(N=N), RunControl(t_end=1.0)), **kwargs)


@pytest.mark.parametrize("excess_length, psi_bar, N", [(2.3, 0.48, 64), (1.6, 0.5, 128), (3.0, 0.45, 32),
                                                       (0.5, 0.48, 64)])
def test_a_carried_start_has_the_new_excess_length_and_mean_and_keeps_the_form(excess_length, psi_bar, N):
    source = solver().initial_state()
    carried = solver(excess_length, psi_bar, N, start=(source.theta, source.psi))
    state = carried.initial_state()
    sp = carried.sp
    area = geometry.enclosed_area(state.theta + sp.circle_angle, sp)
    assert geometry.excess_length(area, sp.length) == pytest.approx(excess_length, abs=1e-12)
    assert state.psi.mean() == pytest.approx(psi_bar, abs=1e-15)
    assert abs(geometry.closure_defect(state.theta + sp.circle_angle)) < 1e-14
    # the pattern of psi is the source's, moved to the new mean (and resampled)
    pattern = resample(source.psi - source.psi.mean(), N)
    assert np.max(np.abs(state.psi - psi_bar - pattern)) < 1e-12
    # the form of the angle is kept: its excess only scaled (the inclination is the source's)
    excess = resample(source.theta - source.theta.mean(), N)
    c = np.dot(state.theta - state.theta.mean(), excess) / np.dot(excess, excess)
    assert np.max(np.abs(state.theta - state.theta.mean() - c * excess)) < 1e-3 * np.max(np.abs(excess))
    if excess_length == 2.3:     # only what N = 64 leaves unresolved of the ellipse's tips
        assert c == pytest.approx(1.0, abs=2e-3)
    else:
        assert (c > 1) == (excess_length > 2.3)


def test_the_same_parameters_carry_a_state_over_unchanged():
    source = solver(N=64)
    state = source.initial_state()
    area = geometry.enclosed_area(state.theta + source.sp.circle_angle, source.sp)
    exact = continuation.target_area(source.sp.length, 2.3)
    again = solver(N=64, start=(state.theta, state.psi)).initial_state()
    # the ellipse's start lies off its excess length by what N = 64 cannot resolve; the carried one on it
    assert np.max(np.abs(again.theta - state.theta)) < 10 * abs(area - exact) / area
    assert np.array_equal(again.psi - again.psi.mean(), state.psi - state.psi.mean())


def test_a_circle_cannot_be_carried_to_a_deflated_shape():
    circle = np.zeros(32)
    with pytest.raises(ConfigError, match="circle"):
        solver(start=(circle, np.full(32, 0.48))).initial_state()


# ---------------------------------------------------------------------- the study
def test_a_chain_runs_there_and_back_for_every_other_point(tmp_path):
    study = study_from_toml(write_chain(tmp_path)[0].read_text())
    rows = [(c.case_id, c.swept["psi_bar"], c.swept["shear_rate"], c.after) for c in study.cases]
    assert rows == [("0000", 0.3, 10, ""), ("0001", 0.3, 20, "0000"), ("0002", 0.3, 40, "0001"),
                    ("0003", 0.3, 20, "0002"), ("0004", 0.3, 10, "0003"),
                    ("0005", 0.5, 10, ""), ("0006", 0.5, 20, "0005"), ("0007", 0.5, 40, "0006"),
                    ("0008", 0.5, 20, "0007"), ("0009", 0.5, 10, "0008")]
    one_way = study_from_toml(write_chain(tmp_path)[0].read_text().replace("back = true", "back = false"))
    assert [c.after for c in one_way.cases] == ["", "0000", "0001", "", "0003", "0004"]
    assert one_way.fingerprint != study.fingerprint


@pytest.mark.parametrize("table, message", [
    ('along = "B2"', "must name a swept key"),
    ('along = "shear_rate"\nback = 1', "must be true or false"),
    ('along = "shear_rate"\nspeed = 2', "unknown key speed"),
])
def test_bad_chains_are_refused(tmp_path, table, message):
    text = write_chain(tmp_path)[0].read_text().split("[chain]")[0] + "[chain]\n" + table + "\n"
    with pytest.raises(ConfigError, match=message):
        study_from_toml(text)


def test_a_chain_is_not_a_refinement(tmp_path):
    text = write_chain(tmp_path)[0].read_text() + '[refine]\naxes = ["shear_rate", "psi_bar"]\n' \
        'tolerance = { shear_rate = 0.5, psi_bar = 0.1 }\n'
    with pytest.raises(ConfigError, match="cannot be combined"):
        study_from_toml(text)


# ---------------------------------------------------------------------- the queue
def test_the_queue_starts_the_longest_chain_first_and_each_case_after_the_one_before():
    todo = [(c, False) for c in ("a0", "a1", "a2", "b0", "b1", "x")]
    cost = {"a0": 1, "a1": 1, "a2": 1, "b0": 2, "b1": 0.5, "x": 2.9}.get
    links = {"a1": "a0", "a2": "a1", "b1": "b0"}
    queue = WorkQueue(todo, cost, links, {c: PENDING for c, _ in todo}, read_end=None)
    first, second, third = queue.pop(), queue.pop(), queue.pop()
    # chains by what is left of them: a (3), x (2.9), b (2.5); a1 and b1 wait for the ones before
    assert (first.case_id, second.case_id, third.case_id) == ("a0", "x", "b0")
    assert first.keep_end and not second.keep_end and first.start is None
    assert queue.pop() is None and len(queue) == 3
    end = (np.zeros(4), np.ones(4))
    assert queue.ended("a0", FINISHED, end) == []
    task = queue.pop()
    assert task.case_id == "a1" and task.start is end and task.keep_end
    # b0 fails: b1 cannot start, and is handed back to be recorded
    broken = queue.ended("b0", FAILED, None)
    assert [c for c, _ in broken] == ["b1"] and "case b0, which ended failed" in broken[0][1]
    assert queue.ended("a1", FINISHED, end) == [] and queue.pop().case_id == "a2"
    assert len(queue) == 0


def test_the_queue_reads_the_ends_of_cases_finished_before():
    read = []

    def read_end(case_id):
        read.append(case_id)
        return ("theta", "psi")

    statuses = {"a0": FINISHED, "a1": PENDING, "b0": MODEL_LIMIT, "b1": PENDING, "b2": PENDING}
    queue = WorkQueue([("a1", True), ("b1", False), ("b2", False)], lambda c: 1.0,
                      {"a1": "a0", "b1": "b0", "b2": "b1"}, statuses, read_end)
    assert read == ["a0"]
    assert sorted(c for c, _ in queue.broken) == ["b1", "b2"]
    task = queue.pop()
    assert (task.case_id, task.resume, task.start) == ("a1", True, ("theta", "psi"))
    assert queue.pop() is None and len(queue) == 0


# ---------------------------------------------------------------------- campaigns
def shape_and_phase_at(f, case_id, which):
    """(shape about its centroid, psi) of the first (which = 0) or last (-1) snapshot of a case."""
    s = case_store(f, case_id).snapshots()
    i = 0 if which == 0 else len(s["t"]) - 1
    z = s["x"][i] + 1j * s["y"][i]
    return z - z.mean(), s["psi"][i]


def test_every_case_of_a_chain_starts_where_the_one_before_ended(decided_chain):
    study, output = decided_chain
    with h5py.File(output, "r") as f:
        decided = [c.case_id for c in study.cases if case_store(f, c.case_id).decision[0] > 0]
        assert decided, "no case was decided before its end time: the test would not see a decided end"
        compared = []
        for c in study.cases:
            assert case_store(f, c.case_id).problems() == []   # the end checkpoint is sound
            if not c.after:
                continue
            before = case_store(f, c.after)
            end = before.end_fields()
            shape, psi = shape_and_phase_at(f, c.case_id, 0)
            assert np.max(np.abs(psi - end[1])) < 1e-13     # the same psi, moved by the round-off its mean gathered
            snapshots = before.snapshots()
            if snapshots["t"][-1] == before.progress[0]:                   # it ended on a snapshot
                ended_shape, ended_psi = shape_and_phase_at(f, c.after, -1)
                assert np.array_equal(ended_psi, end[1])
                assert np.max(np.abs(shape - ended_shape)) < 1e-7          # the shape, centred again
                compared.append(c.case_id)
    assert compared


def test_a_failed_case_stops_its_chain_and_a_retry_runs_it_on(tmp_path, monkeypatch):
    path, output = write_chain(tmp_path)
    study = study_from_toml(path.read_text())
    real_run = runner.run

    def broken(store, *args, **kwargs):
        if store.where.endswith("0002"):
            raise RuntimeError("injected failure")
        return real_run(store, *args, **kwargs)

    monkeypatch.setattr(runner, "run", broken)
    summary = run_campaign(study, output)
    assert summary.exit_status == 1
    states = case_statuses(output)
    assert [states[c] for c in ("0000", "0001", "0002", "0003", "0004")] == [FINISHED, FINISHED, FAILED,
                                                                             FAILED, FAILED]
    assert {states[c] for c in ("0005", "0006", "0007", "0008", "0009")} == {FINISHED}
    with h5py.File(output, "r") as f:
        message = case_store(f, "0003").message
    assert message.startswith("not run: it starts from the end of case 0002, which ended failed")
    monkeypatch.setattr(runner, "run", real_run)
    retried = run_campaign(study, output, resume=True, retry_failed=True)
    assert [r.case_id for r in retried.ran] == ["0002", "0003", "0004"] and retried.exit_status == 0
    (tmp_path / "fresh").mkdir()
    fresh_path, fresh_output = write_chain(tmp_path / "fresh")
    assert run_campaign(study_from_toml(fresh_path.read_text()), fresh_output).exit_status == 0
    assert_same_results(output, fresh_output, attrs=False)


@needs_mpi
def test_a_chain_killed_mid_case_then_resumed_is_bitwise_the_run_without_a_stop(tmp_path):
    path, output = write_chain(tmp_path, t_end=1.2)    # long enough to be seen running on the compiled step
    job = start_job(2, "campaign", path, "--quiet")
    links = {c.case_id: c.after for c in study_from_toml(path.read_text()).cases}

    def a_later_case_is_checkpointed():
        assert job.poll() is None, job.communicate()
        return any(links[c] for c in running_cases(output, checkpointed=True))

    freeze_when(job, a_later_case_is_checkpointed, "a case after the first of its chain has a checkpoint")
    kill_job(job)
    states = case_statuses(output)
    assert PENDING in states.values() and FINISHED in states.values(), states
    result = hpcves("campaign", path, "--resume", n=2)
    assert result.returncode == 0, result.stderr
    assert "from a checkpoint" in result.stderr
    assert set(case_statuses(output).values()) == {FINISHED}
    (tmp_path / "fresh").mkdir()
    fresh_path, fresh_output = write_chain(tmp_path / "fresh", t_end=1.2)
    assert run_campaign(study_from_toml(fresh_path.read_text()), fresh_output).exit_status == 0
    assert_same_results(output, fresh_output, attrs=False)


def test_the_analysis_compares_the_two_legs_of_a_chain_point_by_point(decided_chain, tmp_path):
    from hpcves.reports.analyze import analyze

    study, output = decided_chain
    report = analyze(output, tmp_path / "analysis", case_figures="none", write_to_file=False)
    rows = {r["case"]: r for r in report.rows}
    text = (tmp_path / "analysis" / "attractors.md").read_text()
    assert len(list((tmp_path / "analysis").glob("continuation*.png"))) == 2     # one per psi_bar
    assert "4 points run from S up and S down (2 more from one of them only)" in text
    # at low psi_bar the vesicle tank-treads at one inclination whichever way S came: one attractor
    for up, down in (("0000", "0004"), ("0001", "0003")):
        assert rows[up]["regime"] == rows[down]["regime"] == "TT"
        assert abs(rows[up]["theta_mean"] - rows[down]["theta_mean"]) <= rows[up]["theta_mean_err"] + \
            rows[down]["theta_mean_err"]
    assert "| TT / TT | the same | 2 |" in text


# ---------------------------------------------------------------------- a start from another file
def test_a_stored_state_is_read_back_from_its_snapshot_as_from_its_checkpoint(decided_chain):
    study, output = decided_chain
    with h5py.File(output, "r") as f:
        ended_on_snapshot = [c.case_id for c in study.cases
                             if case_store(f, c.case_id).snapshots()["t"][-1]
                             == case_store(f, c.case_id).progress[0]]
        assert ended_on_snapshot
        store = case_store(f, ended_on_snapshot[0])
        theta, psi, t = store.fields_at(-1.0)
        theta_s, psi_s, t_s = store.fields_at(t + 0.3)          # the nearest snapshot: the last one
    assert t_s == t and np.array_equal(psi_s, psi)
    offset = np.round((theta_s - theta).mean() / (2 * np.pi)) * 2 * np.pi     # a whole turn is the same shape
    # positions are the antiderivative of e^{i theta} on N nodes, whose modes beyond N/2 are lost: the
    # angle read back from them differs by about what theta holds in its highest resolved modes (2e-12
    # at N = 128, 3e-9 at 64, 1e-5 at this N = 32), and by no more
    N = theta.size
    modes = np.abs(np.fft.rfft(theta)) / N
    difference = np.abs(np.fft.rfft(theta_s - offset - theta)) / N
    assert np.max(difference) <= np.max(modes[N // 2 - 4:N // 2 - 1])


def test_a_case_starts_from_the_stored_state_of_a_case_in_another_file(decided_chain, tmp_path):
    from jobs import run_in_process

    study, output = decided_chain
    physics = dataclasses.replace(study.cases[7].case.physics, initial_shape="stored", stored_file=str(output),
                                  stored_case="0007", stored_time=1.0, shear_rate=30.0)
    case = dataclasses.replace(study.cases[7].case, physics=physics, numerics=Numerics(N=64, dt=1e-3),
                               run=dataclasses.replace(study.cases[7].case.run, t_end=0.1, until_decided=False))
    assert run_in_process(case, tmp_path / "from_stored.h5").status == FINISHED
    with h5py.File(output, "r") as f:
        _, source_psi, t = case_store(f, "0007").fields_at(1.0)
    assert t == pytest.approx(1.0)
    with h5py.File(tmp_path / "from_stored.h5", "r") as f:
        started = f["snapshots/psi"][0]
    assert np.max(np.abs(started - resample(source_psi, 64))) < 1e-13


@pytest.mark.parametrize("change, message", [
    ({"stored_file": "nowhere.h5"}, "no such file"),
    ({"stored_case": "9999"}, "has no case '9999'"),
])
def test_a_stored_start_that_is_not_there_is_refused_by_name(decided_chain, change, message):
    from hpcves.run.stored import read_stored_start

    _, output = decided_chain
    physics = Physics(initial_shape="stored", stored_file=str(output), stored_case="0001")
    with pytest.raises(ConfigError, match=message):
        read_stored_start(dataclasses.replace(physics, **change))
