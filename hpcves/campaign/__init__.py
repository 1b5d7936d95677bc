"""A study on MPI: the study file, the campaign file and the changes of its structure, how the ranks
reach it (mpio or rank-0 relay), the entry point (driver.py), its stages (stages.py), the scheduler
that hands cases to the ranks (scheduler.py), and the stage drivers of searches and refinements."""

#: how the ranks of a campaign write its file (campaign/access.py; ``hpcves campaign --io``): "auto" is
#: mpio where h5py has MPI, else relay (one rank: serial); here, where the command line reads it cheaply
IO_MODES = ("auto", "mpio", "relay")
