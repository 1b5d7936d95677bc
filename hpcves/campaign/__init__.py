"""A study on MPI: the study file, the campaign file, rank-0 relay, the driver that schedules
cases over the ranks, and the stage drivers of searches and refinements."""

#: how the ranks of a campaign write its file (campaign/access.py; ``hpcves campaign --io``): "auto" is
#: mpio where h5py has MPI, else relay (one rank: serial); here, where the command line reads it cheaply
IO_MODES = ("auto", "mpio", "relay")
