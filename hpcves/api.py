"""The Python API: what ``hpcves run``, ``campaign`` and ``analyze`` do, callable from a notebook.

Also importable from the package itself (``hpcves.open_campaign(...)``: hpcves/__init__.py
fetches these names from here on first use, so ``import hpcves`` stays light)::

    import hpcves

    case = hpcves.load_case("jobs/case.toml")             # a frozen Case (model/params.py)
    outcome = hpcves.run_case(case, "out/case.h5")         # runs to t_end; Outcome(status, t, ...)
    ds = hpcves.open_case("out/case.h5")                   # xarray.Dataset over time (and snapshots)
    found = hpcves.classify(ds)                            # Classification: regime, period, reason

    study = hpcves.load_study("jobs/demo.toml")
    summary = hpcves.run_campaign(study)                   # in this process (MPI: the command line)
    report = hpcves.analyze(study.output)                  # tables, figures, results into the file
    cases = hpcves.open_campaign(study.output)             # xarray.Dataset over (case, sample)
"""
from __future__ import annotations

from pathlib import Path

from hpcves.analysis.regimes import AnalysisSettings, Classification
from hpcves.analysis.regimes import classify as _classify
from hpcves.campaign.study import Study, load_study
from hpcves.config import load_case
from hpcves.model.params import Case
from hpcves.reports.analyze import analyze
from hpcves.reports.datasets import open_campaign, open_case
from hpcves.run.runner import Outcome

__all__ = ("load_case", "load_study", "run_case", "run_campaign", "analyze", "classify", "open_case",
           "open_campaign", "AnalysisSettings")


def run_case(case: Case | str | Path, path: str | Path, *, resume: bool = False, overwrite: bool = False,
             max_steps: int | None = None, progress=None) -> Outcome:
    """Run one case into the new HDF5 file ``path`` (``hpcves run CASE.toml --out PATH``), or with
    ``resume`` continue the run in ``path`` from its last checkpoint (``case`` is then ignored:
    the file holds it; pass None). ``max_steps`` stops after that many steps (resumable);
    ``progress`` is called with a runner.Tick now and then. Returns the runner's Outcome."""
    from hpcves.run.casefile import create_case_file, open_for_resume, run_file

    if resume:
        h5 = open_for_resume(path)
    else:
        h5 = create_case_file(path, load_case(case) if isinstance(case, (str, Path)) else case, overwrite)
    return run_file(h5, resume=resume, max_steps=max_steps, progress=progress)


def run_campaign(study: Study | str | Path, path: str | Path | None = None, *, resume: bool = False,
                 retry_failed: bool = False, overwrite: bool = False):
    """Run (or with ``resume`` continue) a study in this process, one case after the other, into
    ``path`` (default: the study's output). The same file as ``mpirun -n P hpcves campaign``
    writes, which is how to spread it over cores. Returns the campaign's Summary."""
    from hpcves.campaign.driver import run_campaign as _run_campaign

    study = load_study(study) if isinstance(study, (str, Path)) else study
    return _run_campaign(study, Path(path or study.output), resume=resume, retry_failed=retry_failed,
                         overwrite=overwrite)


def classify(series, settings: AnalysisSettings = AnalysisSettings()) -> Classification:
    """The regime (TT / PT / TU / undecided), period and inclination of one case, from its time
    series: a dict of arrays (``t``, ``theta``, and ``V_psi``, ``V_L``, ``tank_treading_velocity``
    where recorded) or an ``open_case`` Dataset. docs/analysis.md says how it decides."""
    if hasattr(series, "data_vars"):             # an xarray Dataset of open_case
        series = {"t": series["time"].values, **{k: series[k].values for k in series.data_vars
                                                 if "time" in series[k].dims}}
    return _classify(series, settings)
