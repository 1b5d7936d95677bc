"""The errors hpcves raises on purpose, each a message that tells the whole story.

    HpcvesError
    ├── ConfigError      bad input: a parameter, a study or case file, a command-line option
    ├── FileFormatError  a file that is not (or no longer) a readable hpcves run or campaign file
    ├── StorageError     the file system refused a write (full disk, quota, read-only): nothing damaged
    └── LockError        the file is being written by another process (or cannot be locked)

The command line prints any of them as one ``Error:`` line and exits with status 2; a campaign
raises the same class on every rank. Errors that are outcomes of the physics or numerics
(a diverged run, a failed tension solve) are not among them: a case records those and goes on.
"""


class HpcvesError(ValueError):
    """An error hpcves raises on purpose; its message names what is wrong and where.

    A ValueError, as every one of them was before they had a base of their own: readers of damaged
    files catch what h5py raises (store.HDF5_ERRORS, ValueError among it) and let these pass first
    (store.reading)."""


class ConfigError(HpcvesError):
    """A parameter or input file is invalid; the message says which and why."""


class FileFormatError(HpcvesError):
    """An HDF5 file or group that is not (or no longer) a readable hpcves case or campaign."""


class StorageError(HpcvesError):
    """The file system refused a write (full disk, quota, read-only, I/O error): nothing was damaged."""


class LockError(HpcvesError):
    """The file is being written by another process (or cannot be locked at all)."""
