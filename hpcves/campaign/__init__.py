"""A study on MPI: the study file, the campaign file, rank-0 relay, the driver that schedules
cases over the ranks, and the stage drivers of searches and refinements."""
