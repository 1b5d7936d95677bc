"""The stored state a case with ``physics.initial_shape = "stored"`` starts from: a snapshot or the end
of a case of a campaign file (either layout) or of a single run's file."""
from __future__ import annotations

import numpy as np

from hpcves.model.params import ConfigError
from hpcves.run.blocks import find_case
from hpcves.run.store import HDF5_ERRORS, CaseStore, FileFormatError, _first_line, attr_text, open_file, reading


def read_stored_start(physics) -> tuple[np.ndarray, np.ndarray]:
    """(theta_tilde, psi) of the stored state a case with physics.initial_shape = "stored" starts from:
    case ``stored_case`` of the campaign file ``stored_file`` (a single-run file: ``stored_case`` empty)
    at ``stored_time`` (CaseStore.fields_at). Read without locking: the file must not be changing."""
    path, case_id = physics.stored_file, physics.stored_case
    where = f"physics.stored_file = {path!r}"
    try:
        h5 = open_file(path, "r", locking=False)
    except FileNotFoundError:
        raise ConfigError(f"{where}: no such file") from None
    except HDF5_ERRORS as exc:
        raise ConfigError(f"{where}: cannot be read ({_first_line(exc)})") from None
    with h5, reading(path):
        if attr_text(h5.attrs.get("format", "")) == "hpcves-campaign":
            try:
                store = find_case(h5, case_id, where)
            except FileFormatError as exc:
                raise ConfigError(f"{exc} (physics.stored_case)") from None
        elif case_id:
            raise ConfigError(f"{where}: a single-run file; leave physics.stored_case out")
        else:
            store = CaseStore.open(h5, where=f"{path}:{case_id}")
        theta, psi, _ = store.fields_at(physics.stored_time)
    return theta, psi
