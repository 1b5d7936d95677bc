"""What people and tools read: ``hpcves analyze`` (tables, CSV, the analysis group), figures of a
case or a campaign (case pages, shape sequences, animations), and the files as xarray Datasets."""
