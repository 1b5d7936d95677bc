"""The time-stepping scheme of a case: the SBDF2 step with its error estimate, fixed or variable
steps (timestepping.py), and its compiled engine (compiled.py) -- arrays in, arrays out, above the
model whose right-hand side they advance and below everything that records or schedules a run."""
