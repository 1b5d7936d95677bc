"""What people read: ``hpcves analyze`` (tables, CSV, the analysis group), figures of a case
or a campaign, shape sequences and animations."""
