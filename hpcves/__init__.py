"""hpcves: two-phase (multicomponent) vesicles in shear flow.

A spectral boundary-integral solver (:mod:`hpcves.solver.timestepping`) and the
machinery around it: case files, HDF5 output with checkpoints, campaigns on MPI,
the analysis, the command line. The Python API (:mod:`hpcves.api`) is reachable
from here -- ``hpcves.load_case``, ``run_case``, ``load_study``, ``run_campaign``,
``analyze``, ``classify``, ``open_case``, ``open_campaign`` -- and imported on
first use, so that ``import hpcves`` stays light and no module below the API
depends on it; likewise ``hpcves.__version__`` (:mod:`hpcves.version`).

One case runs on one core: :func:`hpcves.run.runner.run` holds the BLAS and
OpenMP thread pools at one thread while it runs (threadpoolctl), whatever was
imported first.
"""

API = ("load_case", "load_study", "run_case", "run_campaign", "analyze", "classify", "open_case",
       "open_campaign", "AnalysisSettings")
__all__ = ("__version__",) + API


def __getattr__(name):
    """The names of the Python API, from :mod:`hpcves.api` on first use (PEP 562), and the version."""
    if name == "__version__":
        from hpcves.version import __version__

        return __version__
    if name in API:
        from hpcves import api

        return getattr(api, name)
    raise AttributeError(f"module 'hpcves' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(API) | {"__version__"})
