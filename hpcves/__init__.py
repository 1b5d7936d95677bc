"""hpcves: two-phase vesicles in shear flow."""
__version__ = "0.1.0"
