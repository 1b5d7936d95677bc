"""The Python API: what ``hpcves run``, ``campaign`` and ``analyze`` do, callable from a notebook.

Also importable from the package itself (``hpcves.open_campaign(...)``: hpcves/__init__.py
fetches these names from here on first use, so ``import hpcves`` stays light)::

    import hpcves

    case = hpcves.load_case("jobs/demo_case.toml")        # a frozen Case (model/params.py)
    outcome = hpcves.run_case(case, "out/case.h5")         # runs to t_end, with a progress bar; Outcome(...)
    ds = hpcves.open_case("out/case.h5")                   # xarray.Dataset over time (and snapshots)
    found = hpcves.classify(ds)                            # Classification: regime, period, reason

    study = hpcves.load_study("jobs/demo.toml")
    summary = hpcves.run_campaign(study)                   # in this process (MPI: the command line)

Both show a progress bar (tqdm.auto: a widget in Jupyter where ipywidgets is installed, text
elsewhere); ``progress=False`` shows none.
    report = hpcves.analyze(study.output)                  # tables, figures, results into the file
    cases = hpcves.open_campaign(study.output)             # xarray.Dataset over (case, sample)
"""
from __future__ import annotations

import functools
import re
import time
from pathlib import Path

from hpcves.analysis.regimes import AnalysisSettings, Classification
from hpcves.analysis.regimes import classify as _classify
from hpcves.campaign.study import Study, load_study
from hpcves.config import load_case
from hpcves.errors import HpcvesError
from hpcves.model.params import Case
from hpcves.reports.analyze import analyze
from hpcves.reports.datasets import open_campaign, open_case
from hpcves.run.runner import Outcome
from hpcves.run.store import FINISHED

#: how the command line's options read as this module's arguments, in the messages of errors raised here
_ARGUMENTS = ((re.compile(r"hpcves run --resume (\S+?)([);,]?)(?=\s|$)"),
               r"hpcves.run_case(None, '\1', resume=True)\2"),
              (re.compile(r"--resume --retry-failed"), "resume=True, retry_failed=True"),
              (re.compile(r"--retry-failed"), "retry_failed=True"),
              (re.compile(r"--resume"), "resume=True"),
              (re.compile(r"--overwrite"), "overwrite=True"))


def _in_python_words(function):
    """``function`` whose hpcves errors name its arguments (``overwrite=True``) where the messages,
    shared with the command line, name options (``--overwrite``)."""
    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        try:
            return function(*args, **kwargs)
        except HpcvesError as exc:
            text = str(exc)
            for pattern, words in _ARGUMENTS:
                text = pattern.sub(words, text)
            if text == str(exc):
                raise
            raise type(exc)(text) from None
    return wrapper


__all__ = ("load_case", "load_study", "run_case", "run_campaign", "analyze", "classify", "open_case",
           "open_campaign", "AnalysisSettings")


@_in_python_words
def run_case(case: Case | str | Path, path: str | Path, *, resume: bool = False, overwrite: bool = False,
             max_steps: int | None = None, progress=True) -> Outcome:
    """Run one case into the new HDF5 file ``path`` (``hpcves run CASE.toml --out PATH``), or with
    ``resume`` continue the run in ``path`` from its last checkpoint (``case`` is then ignored:
    the file holds it; pass None). ``max_steps`` stops after that many steps (resumable).
    ``progress``: True, a bar over simulated time; False, none; or a function called with a
    runner.Tick now and then. Returns the runner's Outcome."""
    from hpcves.run.casefile import create_case_file, open_for_resume, run_file

    if resume:
        opened = open_for_resume(path)
    else:
        opened = create_case_file(path, load_case(case) if isinstance(case, (str, Path)) else case, overwrite)
    bar = CaseBar(Path(path).name) if progress is True else None
    outcome = None
    try:
        outcome = run_file(opened, resume=resume, max_steps=max_steps, progress=bar or progress or None)
        return outcome
    finally:
        if bar is not None:             # a finished run (decided early, too) shows 100 %
            bar.close(done=outcome is not None and outcome.status == FINISHED)


@_in_python_words
def run_campaign(study: Study | str | Path, path: str | Path | None = None, *, resume: bool = False,
                 retry_failed: bool = False, overwrite: bool = False, progress: bool = True):
    """Run (or with ``resume`` continue) a study in this process, one case after the other, into
    ``path`` (default: the study's output). The same file as ``mpirun -n P hpcves campaign``
    writes, which is how to spread it over cores. ``progress``: a bar per stage over the cases'
    cost (False: none). Returns the campaign's Summary."""
    from hpcves.campaign.driver import run_campaign as _run_campaign

    study = load_study(study) if isinstance(study, (str, Path)) else study
    bars = CampaignBars(study.name)
    try:
        return _run_campaign(study, Path(path or study.output), resume=resume, retry_failed=retry_failed,
                             overwrite=overwrite, **(bars.callbacks() if progress else {}))
    finally:
        bars.close()


def classify(series, settings: AnalysisSettings = AnalysisSettings()) -> Classification:
    """The regime (TT / PT / TU / undecided), period and inclination of one case, from its time
    series: a dict of arrays (``t``, ``theta``, and ``V_psi``, ``V_L``, ``tank_treading_velocity``
    where recorded) or an ``open_case`` Dataset. docs/analysis.md says how it decides."""
    if hasattr(series, "data_vars"):             # an xarray Dataset of open_case
        series = {"t": series["time"].values, **{k: series[k].values for k in series.data_vars
                                                 if "time" in series[k].dims}}
    return _classify(series, settings)


# ---------------------------------------------------------------------- progress bars (tqdm.auto)
class CaseBar:
    """A bar over one run's simulated time, fed runner.Ticks: a widget in Jupyter, text elsewhere."""

    def __init__(self, label: str):
        self.label, self.bar = label, None

    def __call__(self, tick) -> None:
        if self.bar is None:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=tick.t_end, desc=self.label, unit="t", bar_format=_BAR)
        self.bar.n = min(tick.t, tick.t_end)
        self.bar.set_postfix_str(f"{tick.steps_per_second:,.0f} steps/s, theta = {tick.theta:.3f}", refresh=False)
        self.bar.refresh()

    def close(self, done: bool = False) -> None:
        """Close the bar; ``done``: the run ended, and the bar shows it full (its last tick may have come
        before t_end, or the run stopped once decided)."""
        if self.bar is not None:
            if done:
                self.bar.n = self.bar.total
                self.bar.refresh()
            self.bar.close()


class CampaignBars:
    """A bar per stage of a campaign run in this process, over the cost (steps x N^2) of its cases,
    with how many cases ended and failed (those that ended before this call count too)."""

    def __init__(self, name: str):
        self.name, self.bar, self.stage = name, None, None
        self.total, self.before, self.shown = 0, (0, 0), 0.0

    def callbacks(self) -> dict:
        return {"announce": self.announce, "display": self.show}

    def announce(self, text: str, n_cases, ended_before) -> None:
        if n_cases is None:
            return
        from tqdm.auto import tqdm

        self.close()
        self.total, self.before = n_cases, ended_before
        self.bar = tqdm(total=100.0, desc=self.name, bar_format=_BAR)

    def show(self, stage, every: float = 0.2) -> None:
        """Called with a scheduler.StageProgress at every scheduling turn; redraws at most every ``every`` s."""
        self.stage = stage
        if self.bar is None or time.monotonic() - self.shown < every:
            return
        self.shown = time.monotonic()
        self.bar.n = 100.0 * stage.fraction
        self.bar.set_postfix_str(f"{self.before[0] + stage.ended}/{self.total} cases, {stage.running} running, "
                                 f"{self.before[1] + stage.failed} failed", refresh=False)
        self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            if self.stage is not None:
                self.show(self.stage, every=0.0)          # where the stage ended
            self.bar.close()
        self.bar, self.stage, self.shown = None, None, 0.0


_BAR = "{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}{postfix}]"
