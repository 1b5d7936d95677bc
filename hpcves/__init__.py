"""hpcves: two-phase (multicomponent) vesicles in shear flow.

A spectral boundary-integral solver (:mod:`hpcves.run.timestepping`) and the
machinery around it: case files, HDF5 output with checkpoints, the command line.

One case runs on one core: :func:`hpcves.run.runner.run` holds the BLAS and
OpenMP thread pools at one thread while it runs (threadpoolctl), whatever was
imported first.
"""

__version__ = "0.1.0"
