"""``xarray.open_dataset(path, engine="hpcves")`` and ``xarray.open_datatree(path, engine="hpcves")``.

An xarray backend (https://docs.xarray.dev/en/stable/internals/how-to-add-new-backend.html),
registered under the ``xarray.backends`` entry point in pyproject.toml: the file of ``hpcves run``
opens as :func:`~hpcves.reports.datasets.open_case` gives it, a campaign file as
:func:`~hpcves.reports.datasets.open_campaign` does (``case="0003"``: that case alone), and
``open_datatree`` gives a campaign's tree. xarray imports this module to list its engines, so it
imports nothing heavy at the top.
"""
from __future__ import annotations

import os

from xarray.backends import BackendEntrypoint


def _kind(filename) -> str:
    """"case", "campaign" or "" (not an hpcves file, or not a file at all)."""
    import h5py

    from hpcves.campaign.file import FORMAT as CAMPAIGN_FORMAT
    from hpcves.run.store import FORMAT as CASE_FORMAT
    from hpcves.run.store import attr_text

    try:
        with h5py.File(filename, "r", locking=False) as h5:
            fmt = attr_text(h5.attrs.get("format", ""))
    except (OSError, TypeError, ValueError):
        return ""
    return {CASE_FORMAT: "case", CAMPAIGN_FORMAT: "campaign"}.get(fmt, "")


class HpcvesBackendEntrypoint(BackendEntrypoint):
    """hpcves run and campaign files: trimmed to what was computed, with CF metadata."""

    description = "hpcves run and campaign files (vesicles in shear flow), trimmed and CF-described"
    url = "https://github.com/hpcves/hpcves/blob/main/README.md#from-python-a-notebook"
    open_dataset_parameters = ("filename_or_obj", "drop_variables", "case", "variables", "snapshots")

    def open_dataset(self, filename_or_obj, *, drop_variables=None, case=None, variables=None, snapshots=True):
        from hpcves.reports.datasets import open_campaign, open_case

        path = os.fspath(filename_or_obj)
        if _kind(path) == "campaign" and case is None:
            ds = open_campaign(path, variables=variables)
        else:
            ds = open_case(path, case, variables=variables, snapshots=snapshots)
        return ds.drop_vars(drop_variables or [], errors="ignore")

    def open_datatree(self, filename_or_obj, *, drop_variables=None, variables=None):
        import xarray as xr

        from hpcves.reports.datasets import open_campaign

        path = os.fspath(filename_or_obj)
        if _kind(path) != "campaign":
            return xr.DataTree(self.open_dataset(path, drop_variables=drop_variables, variables=variables))
        tree = open_campaign(path, variables=variables, tree=True)
        return tree.map_over_datasets(lambda ds: ds.drop_vars(drop_variables or [], errors="ignore"))

    def open_groups_as_dict(self, filename_or_obj, **kwargs):
        return {node.path: node.to_dataset(inherit=False) for node in self.open_datatree(filename_or_obj,
                                                                                        **kwargs).subtree}

    def guess_can_open(self, filename_or_obj) -> bool:
        try:
            path = os.fspath(filename_or_obj)
        except TypeError:
            return False
        return os.path.isfile(path) and _kind(path) != ""
