"""make reproduce's campaign loop (analysis/reproduce.py run_campaigns): it stops at a campaign that
ended with work left, passes a SIGTERM on to the running campaign and waits for it, and counts the
wall time of every call. Fake ``mpirun`` and ``hpcves`` stand in for the real ones."""
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "analysis"))

import reproduce  # noqa: E402

FAKE_MPIRUN = """\
import os, sys
os.execv(sys.executable, [sys.executable] + sys.argv[3:])      # drop "-n NP"
"""

#: campaign: logs its study and, for a study named "slow", says it is ready and waits for a signal;
#: status: exit status 3 (work left) for the study named in the environment, else 0
FAKE_HPCVES = """\
import json, os, signal, sys, time
from pathlib import Path
log = Path(os.environ["FAKE_LOG"])
command, target = sys.argv[1], [a for a in sys.argv[2:] if not a.startswith("--")][0]
name = Path(target).stem
if command == "campaign":
    with log.open("a") as f:
        f.write(f"campaign {name}{' --retry-failed' if '--retry-failed' in sys.argv else ''}\\n")
    if name == "slow":
        def stop(signum, frame):
            with log.open("a") as f:
                f.write(f"{name} got {signal.Signals(signum).name}\\n")
            sys.exit(0)
        signal.signal(signal.SIGTERM, stop)
        Path(os.environ["FAKE_READY"]).write_text("ready")
        deadline = time.monotonic() + 120          # guards against a hang only
        while time.monotonic() < deadline:
            time.sleep(0.05)
        sys.exit(5)
    sys.exit(0)
left = os.environ.get("FAKE_LEFT", "")
output = Path(target).stem
print(json.dumps({"left": "cases to run" if output == left else None}))
sys.exit(3 if output == left else 0)
"""


def _studies(tmp_path: Path, names) -> dict:
    """A study file per name (the demo study with its own output)."""
    demo = (ROOT / "jobs" / "demo.toml").read_text()
    jobs = {}
    for name in names:
        text = demo.replace('name = "demo"', f'name = "{name}"').replace(
            'output = "out/demo/demo.h5"', f'output = "{(tmp_path / name).as_posix()}.h5"')
        path = tmp_path / f"{name}.toml"
        path.write_text(text)
        jobs[name] = path.as_posix()
    return jobs


def _fakes(tmp_path: Path) -> tuple[list[str], str]:
    (tmp_path / "mpirun.py").write_text(FAKE_MPIRUN)
    hpcves = tmp_path / "hpcves"
    hpcves.write_text(f"#!{sys.executable}\n" + FAKE_HPCVES)
    hpcves.chmod(0o755)
    return [sys.executable, str(tmp_path / "mpirun.py")], str(hpcves)


def test_a_campaign_with_work_left_stops_the_reproduction(tmp_path, monkeypatch):
    jobs = _studies(tmp_path, ["first", "second", "third"])
    mpirun, hpcves = _fakes(tmp_path)
    monkeypatch.setenv("FAKE_LOG", str(tmp_path / "log"))
    monkeypatch.setenv("FAKE_LEFT", "second")
    ledger = tmp_path / "walls.json"
    with pytest.raises(SystemExit) as stopped:
        reproduce.run_campaigns(jobs, mpirun, 2, hpcves, ledger)
    assert "second.toml stopped before it was complete (cases to run)" in str(stopped.value.code)
    assert (tmp_path / "log").read_text().split("\n")[:-1] == ["campaign first", "campaign second"]
    walls = json.loads(ledger.read_text())
    assert set(walls) == {"first", "second"} and all(w > 0 for w in walls.values())
    monkeypatch.setenv("FAKE_LEFT", "")                     # the rerun goes on from there
    for name in ("first", "second"):                        # the files the campaigns made (the fake makes none)
        (tmp_path / f"{name}.h5").touch()
    again = reproduce.run_campaigns(jobs, mpirun, 2, hpcves, ledger)
    assert set(again) == {"first", "second", "third"}
    assert all(json.loads(ledger.read_text())[n] > walls.get(n, 0) for n in again)


def test_retry_failed_is_passed_on_to_every_campaign(tmp_path, monkeypatch):
    jobs = _studies(tmp_path, ["first", "second"])
    mpirun, hpcves = _fakes(tmp_path)
    monkeypatch.setenv("FAKE_LOG", str(tmp_path / "log"))
    reproduce.run_campaigns(jobs, mpirun, 2, hpcves, tmp_path / "walls.json", retry_failed=True)
    assert (tmp_path / "log").read_text().split("\n")[:-1] == ["campaign first --retry-failed",
                                                               "campaign second --retry-failed"]


def test_a_sigterm_is_passed_on_to_the_running_campaign_and_stops_the_reproduction(tmp_path):
    jobs = _studies(tmp_path, ["quick", "slow", "never"])
    mpirun, hpcves = _fakes(tmp_path)
    ledger, ready = tmp_path / "walls.json", tmp_path / "ready"
    script = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(ROOT / 'analysis')!r})
        import reproduce
        reproduce.run_campaigns({jobs!r}, {mpirun!r}, 2, {hpcves!r}, __import__('pathlib').Path({str(ledger)!r}))
    """)
    env = {**os.environ, "FAKE_LOG": str(tmp_path / "log"), "FAKE_READY": str(ready)}
    runner = subprocess.Popen([sys.executable, "-c", script], env=env, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120                       # guards against a hang only
    while not ready.exists():
        assert runner.poll() is None and time.monotonic() < deadline, runner.stderr.read()
        time.sleep(0.05)
    runner.send_signal(signal.SIGTERM)
    _, stderr = runner.communicate(timeout=120)
    assert runner.returncode == 1
    assert "stopped by SIGTERM during campaign slow" in stderr
    assert (tmp_path / "log").read_text().split("\n")[:-1] == ["campaign quick", "campaign slow", "slow got SIGTERM"]
    assert set(json.loads(ledger.read_text())) == {"quick", "slow"}


def test_prune_figures_keeps_what_the_report_shows(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    directory = Path("docs/reproduction")
    (directory / "fine").mkdir(parents=True)
    for name in ("a_phase_diagram.png", "a_periods.png", "old_critical_shear.png", "fine/a_phase_diagram.png"):
        (directory / name).write_bytes(b"png")
    report = Path("REPRODUCTION.md")
    report.write_text("# r\n\n![a_phase_diagram](docs/reproduction/a_phase_diagram.png)\n")
    stale = reproduce.prune_figures(report, directory)
    assert sorted(p.name for p in stale) == ["a_periods.png", "old_critical_shear.png"]
    assert sorted(p.relative_to(directory).as_posix() for p in directory.rglob("*.png")) == [
        "a_phase_diagram.png", "fine/a_phase_diagram.png"]      # the fine set's own folder is left alone


def _meta(name, campaign, analysis, doubts=(), notes=()):
    return {"study": name, "job": f"jobs/reproduce/{name}.toml", "written": "2026-12-05", "machine": "m",
            "processor": "x86_64", "ranks": 2, "numerics": "N = 64", "cases": 3, "compute_s": 120.0,
            "campaign_wall_s": campaign, "analysis_wall_s": analysis, "pages": 0, "doubts": list(doubts),
            "notes": list(notes)}


def test_a_section_keeps_its_markdown_and_what_its_run_took(tmp_path):
    path = tmp_path / "sections" / "a.md"
    meta = _meta("a", 60.0, 6.0, doubts=["a case 0001: undecided -- not settled"])
    reproduce.write_section(path, ["## A", "", "text -- with a --> in it", ""], meta)
    assert reproduce.read_section(path) == (meta, "## A\n\ntext -- with a --> in it\n")
    assert reproduce.read_section(tmp_path / "sections" / "none.md") is None
    (tmp_path / "foreign.md").write_text("## not a section\n")
    with pytest.raises(SystemExit, match="not a section of the reproduction"):
        reproduce.read_section(tmp_path / "foreign.md")


def test_the_report_is_assembled_from_the_sections_there_are(tmp_path, monkeypatch):
    """make reproduce STUDY=... rewrites some sections; the report is put together from all of them, in
    the order of STUDIES, with what each took, the studies not run yet named, and every doubt."""
    monkeypatch.setattr(reproduce, "STUDIES", ("a", "b", "c"))
    monkeypatch.setitem(reproduce.SECTION_DIRS, "coarse", tmp_path / "sections")
    note = "the old sections' analysis is not split"
    reproduce.write_section(tmp_path / "sections" / "c.md", ["## C"], _meta("c", 1800.0, None, ["c: refinement "
                                                                                            "stopped"], [note]))
    reproduce.write_section(tmp_path / "sections" / "a.md", ["## A"], _meta("a", 3600.0, 120.0, notes=[note]))
    report = tmp_path / "REPRODUCTION.md"
    reproduce.assemble(report, "coarse")
    text = report.read_text()
    assert text.index("## A") < text.index("## C") < text.index("## What looks unconverged")
    assert "**Wall time: 1.53 h in all**" in text                   # 1.5 h of campaigns + 2 min of analysis
    assert "not recorded for c" in text and text.count(note) == 1
    assert "Not run yet: b (`make reproduce STUDY=b`)" in text
    assert "* c: refinement stopped" in text
    assert "## The publication's claims beside hpcves" in text and "not run yet (`make reproduce STUDY=sc_b2`)" in text


def test_an_unknown_study_is_refused(capsys):
    with pytest.raises(SystemExit) as refused:
        reproduce.main(["--study", "homogeneous,nonesuch"])
    assert refused.value.code == 2 and "no campaign nonesuch" in capsys.readouterr().err


def test_the_wall_ledger_adds_calls_and_starts_again_with_a_new_file(tmp_path):
    ledger = tmp_path / "walls.json"
    reproduce._add_walls(ledger, {"a": 10.0, "b": 5.0})
    assert reproduce._add_walls(ledger, {"a": 2.5}) == {"a": 12.5, "b": 5.0}       # a resumed campaign
    assert reproduce._add_walls(ledger, {"a": 4.0}, restart=("a",)) == {"a": 4.0, "b": 5.0}   # made anew


def test_a_regime_sequence_merges_neighbours_of_one_regime():
    """The contrast sections' 'along lambda' lines (reproduce.contrast_section)."""
    pairs = [(0.1, "TT"), (0.5, "PT"), (1.0, "PT"), (2.5, "PT"), (12.5, "TU"), (62.5, "TU")]
    assert reproduce._runs(pairs) == "TT (0.1) -> PT (0.5 - 2.5) -> TU (12.5 - 62.5)"
    assert reproduce._runs([]) == ""


def test_a_section_says_what_the_vesicles_add_to_the_stress_or_how_to_get_it(monkeypatch, tmp_path):
    """reproduce.stress_lines (issue 66): [eta] and N1 of the settled cases by regime with where the extremes
    lie and the maps; for a campaign file without the rheology series, how to run it again with them."""
    from types import SimpleNamespace

    monkeypatch.setattr(reproduce, "superseded", lambda source: set())
    nan = float("nan")

    def row(case, S, psi, regime, eta, n1):
        return {"case": case, "shear_rate": S, "psi_bar": psi, "excess_length": 0.94, "viscosity_ratio": 1.0,
                "regime": regime, "intrinsic_viscosity": eta, "normal_stress_coefficient": n1,
                "intrinsic_viscosity_err": 1e-5, "intrinsic_viscosity_dt_err": 2e-5, "intrinsic_viscosity_N_err": nan}
    rows = [row("0000", 10, 0.3, "TT", 1.52, 2.0), row("0001", 40, 0.3, "PT", 1.61, 1.9),
            row("0002", 40, 0.5, "undecided", nan, nan)]
    figures = [tmp_path / "delta094_S_psi_intrinsic_viscosity.png", tmp_path / "delta094_S_psi_phase_diagram.png"]
    c = SimpleNamespace(report=SimpleNamespace(rows=rows, source=None), figures=figures, name="delta094_S_psi",
                        study=SimpleNamespace(output="out/reproduce/delta094_S_psi.h5"))
    text = "\n".join(reproduce.stress_lines(c))
    assert "of the 2 settled cases" in text and "TT (1): [eta] 1.52-1.52" in text and "PT (1)" in text
    assert "Least [eta] 1.52 (TT, S = 10, psi_bar = 0.3), largest 1.61 (PT, S = 40, psi_bar = 0.3)" in text
    assert "at most 3e-05" in text and "intrinsic_viscosity.png" in text and "phase_diagram" not in text
    assert "(1 such neighbours), [eta] changes across the transition by +5.92% to +5.92%" in text
    for r in rows:
        r["intrinsic_viscosity"] = nan
    text = "\n".join(reproduce.stress_lines(c))
    assert "predates the rheology series" in text and "make reproduce STUDY=delta094_S_psi" in text
