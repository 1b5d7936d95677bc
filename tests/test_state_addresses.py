"""``status`` reads each case's state of a campaign file of format 1 (a group per case) from where its
bytes lie (index/addresses): the same table as through HDF5, never from addresses a rewritten file no
longer honours, and damaged cases still found. (Format 2 reads each block's arrays whole.)"""
from __future__ import annotations

import h5py
import pytest

from hpcves.campaign import file as campaign_file
from hpcves.campaign.file import CampaignFile, StateReader
from hpcves.campaign.study import study_from_toml
from hpcves.run.store import FAILED, FINISHED, INTERRUPTED, RUNNING

STUDY = """
[campaign]
name = "addresses"
t_end = 0.01
[numerics]
N = 16
dt = 1e-3
[run]
sample_interval = 0.005
snapshot_interval = 0.005
checkpoint_interval = 0.005
[sweep]
shear_rate = {{ linspace = [1, 10, {n}] }}
"""


@pytest.fixture
def campaign(tmp_path, monkeypatch):
    """A file of 40 cases in every state, with progress and messages of their own."""
    monkeypatch.setattr(campaign_file, "WRITES_VERSION", 1)
    path = tmp_path / "c.h5"
    study = study_from_toml(STUDY.format(n=40))
    with h5py.File(path, "w") as h5:
        campaign = CampaignFile.create(h5, study)
        for i, case_id in enumerate(campaign.case_ids):
            store = campaign.store(case_id)
            status = (FINISHED, FAILED, RUNNING, INTERRUPTED, None)[i % 5]
            if status is not None:
                store.set_status(status, f"case {i} says {'x' * i}")
                store.set_progress(0.001 * i, 0.01, 2.5 * i, 100.0 + i)
    return path


def rows(path, fast=True, monkeypatch=None):
    with h5py.File(path, "r") as h5:
        if not fast:
            monkeypatch.setattr(StateReader, "read", lambda self, i: None)
        return CampaignFile.check(h5, str(path)).table(addresses=True)


def test_the_addresses_give_the_table_hdf5_gives(campaign, monkeypatch):
    with h5py.File(campaign, "r") as h5:
        reader = StateReader(h5, CampaignFile(h5).case_ids)
        assert reader.fd is not None                   # the addresses are used
    fast = rows(campaign)
    slow = rows(campaign, fast=False, monkeypatch=monkeypatch)
    assert fast == slow
    assert {r["status"] for r in fast} == {"finished", "failed", "running", "interrupted", "pending"}
    assert fast[7]["message"] == "case 7 says xxxxxxx" and fast[7]["wall"] == 17.5


def test_a_file_rewritten_elsewhere_is_read_through_hdf5(campaign, tmp_path, monkeypatch):
    """A copy object by object (as h5repack makes) moves the data; index/addresses is copied as it was."""
    copy = tmp_path / "copy.h5"
    with h5py.File(campaign, "r") as src, h5py.File(copy, "w") as dst:
        for key, value in src.attrs.items():
            dst.attrs[key] = value
        for name in ("index", "cases"):
            src.copy(name, dst)
    with h5py.File(copy, "r") as h5:
        assert (h5["index/addresses"][:] == h5py.File(campaign, "r")["index/addresses"][:]).all()
        assert StateReader(h5, CampaignFile(h5).case_ids).fd is None
    assert rows(copy) == rows(campaign, fast=False, monkeypatch=monkeypatch)


def test_addresses_that_lie_are_caught_by_the_sample(campaign, tmp_path):
    """Every eighth case is checked against HDF5: a wrong address among them and none are trusted."""
    with h5py.File(campaign, "r+") as h5:
        h5["index/addresses"][5, 0] += 8
    with h5py.File(campaign, "r") as h5:
        assert StateReader(h5, CampaignFile(h5).case_ids).fd is None


def test_an_unreadable_case_is_damaged_though_its_bytes_are_read_elsewhere(campaign):
    with h5py.File(campaign, "r") as h5:
        address = h5py.h5o.get_info(h5["cases/0013"].id).addr      # not one of the sampled cases
    with open(campaign, "r+b") as f:
        f.seek(address)
        byte = f.read(1)
        f.seek(address)
        f.write(bytes([byte[0] ^ 0x40]))
    table = {r["case"]: r for r in rows(campaign)}
    assert table["0013"]["status"] == "damaged" and "unreadable" in table["0013"]["message"]
    assert table["0012"]["status"] == "running"


def test_files_without_addresses_are_read_as_before(campaign, monkeypatch):
    with h5py.File(campaign, "r+") as h5:
        del h5["index/addresses"]
    with h5py.File(campaign, "r") as h5:
        assert StateReader(h5, CampaignFile(h5).case_ids).fd is None
    slow = rows(campaign)
    monkeypatch.setattr(campaign_file, "_summary", lambda cases, case_id: None)     # the plain h5py way
    assert rows(campaign) == slow
