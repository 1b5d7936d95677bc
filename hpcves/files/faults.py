"""Deterministic fault injection, for the tests that kill campaigns at exact moments (tests/faults.py).

``HPCVES_FAULT=point[:n][@rank]`` makes the process kill itself with SIGKILL
the n-th time (default: the first) it passes :func:`point` ``point``, on MPI
rank ``rank`` only if one is given. The points are where a kill is most
likely to hurt:

* ``block-grown``: after each array of a block grew by a stage's (or a new file's) cases (campaign
  format 2: run/blocks.py), while a file is created or a search stage added;
* ``case-laid-out``: the same moment in files of format 1, after each case is laid out;
* ``publish``: a finished ``.partial`` is about to be renamed over the file (atomic.py);
* ``checkpoint``: inside a checkpoint write, once after the slot is marked invalid and once
  after its data are written, before it is marked valid again (run/store.py);
* ``finished``: a case has just recorded that it finished (runner.py);
* ``analysis-stored``: ``hpcves analyze`` has written its results into the copy, before the rename;
* ``verdicts-stored``: a staged campaign's rank 0 has written the verdicts of a stage in place, before
  the next stage's cases are added (campaign/stages.py).

Without the variable, which is the case outside those tests, :func:`point` returns at once.
"""
from __future__ import annotations

import os
import re
import signal

from hpcves.errors import ConfigError

#: the points a fault may be injected at (the list above)
POINTS = ("block-grown", "case-laid-out", "publish", "checkpoint", "finished", "analysis-stored", "verdicts-stored")
_SPEC = os.environ.get("HPCVES_FAULT", "")
_FORM = re.compile(r"([a-z-]+)(?::([1-9][0-9]{0,8}))?(?:@([0-9]{1,6}))?")
_passes: dict[str, int] = {}


def _parse(spec: str) -> tuple[str, int, int | None]:
    """(point, n, rank or None) of ``point[:n][@rank]``; ConfigError where it is not of that form."""
    found = _FORM.fullmatch(spec)
    if found is None or found[1] not in POINTS:
        raise ConfigError(f"HPCVES_FAULT={spec!r}: not point[:n][@rank] with n >= 1, a point one of "
                          f"{', '.join(POINTS)} (a test's fault injection; unset it to run normally)")
    return found[1], int(found[2] or 1), (int(found[3]) if found[3] is not None else None)


def check_environment() -> None:
    """Refuse a malformed ``HPCVES_FAULT`` up front (the command line calls this before any work)."""
    if _SPEC:
        _parse(_SPEC)


def _rank() -> int:
    for variable in ("OMPI_COMM_WORLD_RANK", "PMI_RANK", "PMIX_RANK", "SLURM_PROCID"):
        if variable in os.environ:
            return int(os.environ[variable])
    return 0


def point(name: str) -> None:
    """Kill this process here if ``HPCVES_FAULT`` asks for it (see the module's docstring)."""
    if not _SPEC:
        return
    target, count, rank = _parse(_SPEC)
    if name != target or (rank is not None and rank != _rank()):
        return
    _passes[name] = _passes.get(name, 0) + 1
    if _passes[name] == count:
        os.kill(os.getpid(), signal.SIGKILL)
