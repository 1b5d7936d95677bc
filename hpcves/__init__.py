"""hpcves: two-phase (multicomponent) vesicles in shear flow.

A spectral boundary-integral solver (:mod:`hpcves.run.timestepping`) and the
machinery around it: case files, HDF5 output with checkpoints, the command line.

One case runs on one core. Unless the environment says otherwise, the BLAS and
OpenMP thread pools are set to a single thread before numpy is loaded: the
matrices here are ~100 x 100, where threading only costs (spin-waits of a few
milliseconds per call were measured with OpenBLAS on two cores).
"""
import os as _os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

__version__ = "0.1.0"
