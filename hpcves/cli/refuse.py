"""A file given to the wrong command (a study to ``run``, a campaign file to ``run --resume``, a
TOML to ``status``): one line that names the command that takes it, exit status 2."""
from __future__ import annotations

import os
import stat
import tomllib

from hpcves.campaign.file import FORMAT as CAMPAIGN_FORMAT
from hpcves.cli.terminal import fail
from hpcves.run.store import HDF5_ERRORS, attr_text, open_file


def _toml_of(path) -> dict | None:
    """The parsed TOML of ``path`` if it is a regular, non-empty text file of TOML (at most 1 MB), else
    None: the reader the command meant to use says what is wrong with it."""
    try:
        info = os.stat(path)
        if not stat.S_ISREG(info.st_mode) or info.st_size == 0 or info.st_size > 1 << 20:
            return None
        with open(path, "rb") as f:
            return tomllib.load(f) or None
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError):
        return None


def refuse_a_study_as_case(path) -> None:
    """``hpcves run STUDY.toml``: a study (a [campaign] table) is run by ``hpcves campaign``."""
    data = _toml_of(path)
    if data is not None and isinstance(data.get("campaign"), dict):
        fail(f"{path}: a study file (it has a [campaign] table), not a case: `hpcves campaign {path}` runs it "
             f"(`mpirun -n P hpcves campaign {path}` on P ranks)")


def refuse_a_campaign_file(path) -> None:
    """``hpcves run --resume CAMPAIGN.h5``: a campaign file is continued by ``hpcves campaign --resume``."""
    try:
        with open_file(path, "r", locking=False) as h5:
            kind = attr_text(h5.attrs.get("format", ""))
            source = attr_text(h5.attrs.get("campaign_toml", ""))
    except (OSError, *HDF5_ERRORS):
        return                                        # open_for_resume says what is wrong with it
    if kind == CAMPAIGN_FORMAT:
        fail(f"{path}: a campaign file, not a case's: `hpcves campaign STUDY.toml --resume` continues it"
             + (" (the study it was made from is stored in the file: campaign_toml)" if source else ""))


def refuse_a_study_file(path, command: str) -> None:
    """A study file (TOML with a [campaign] table) given where a campaign file is wanted: say which
    command takes it, and where its campaign file is."""
    data = _toml_of(path)
    if data is None:
        return                                        # not a TOML text: the HDF5 reader says what it is
    if isinstance(data.get("campaign"), dict):
        output = data["campaign"].get("output")
        fail(f"{path}: a study file, not a campaign file: `hpcves {command} "
             + (f"{output}`" if output else "<its output file>`") + f" for its campaign, `hpcves campaign {path}` "
             "to run it")
    fail(f"{path}: a case file (TOML), not a campaign file: `hpcves run {path} --out FILE.h5` runs it, and "
         f"`hpcves {command}` takes the campaign file of `hpcves campaign`")
