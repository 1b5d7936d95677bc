"""One case: when to sample, snapshot and checkpoint, what is recorded, when a case is decided, the
case store (HDF5), the run loop, and what a step costs here (the time stepping itself: solver/)."""
