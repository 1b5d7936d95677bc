"""The version of hpcves: written into every file it makes (pyproject.toml reads it from here)."""

__version__ = "0.1.0"
