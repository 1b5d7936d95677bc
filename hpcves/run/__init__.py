"""One case: the SBDF2 time stepping (and its compiled engine), when to sample, snapshot and
checkpoint, what is recorded, when a case is decided, the case store (HDF5) and the run loop."""
