"""Checksums (case format 5): a flipped bit in any dataset a case records is caught and named.

Every checkpoint slot carries the checksum of each array, its scalars and its counters; an ended
case carries those of the valid part of every series and snapshot record. A bit flipped in any of
them is named by CaseStore.problems (and so by ``status --check``, ``analyze`` and the resume
checks); a resumed run passes over a checkpoint that fails its checksums and resumes from the other
one, bitwise identical to an uninterrupted run; with both damaged it refuses, exit 2.
"""
import logging
import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest

from conftest import tiny_study
from hpcves.campaign.driver import run_campaign
from hpcves.campaign.study import study_from_toml
from hpcves.config import case_from_toml
from hpcves.run.diagnostics import SERIES
from hpcves.run.store import FINISHED, INTERRUPTED, SNAPSHOT_RECORDS, CaseStore, FileFormatError
from hpcves.solver.timestepping import State
from jobs import SHORT, case_view, resume_in_process, run_in_process, same_case_files

HPCVES = [sys.executable, "-m", "hpcves.cli"]

CASE = SHORT.format(t_end=0.3, checkpoint=0.04)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A finished case file, and one interrupted at step 97 with both checkpoint slots valid."""
    d = tmp_path_factory.mktemp("checksums")
    case = case_from_toml(CASE)
    assert run_in_process(case, d / "whole.h5").status == FINISHED
    assert run_in_process(case, d / "cut.h5", max_steps=97).status == INTERRUPTED
    with h5py.File(d / "cut.h5", "r") as f:
        assert all(f[f"checkpoint/{s}/meta"][0] == 1 for s in ("slot0", "slot1"))
    return d


def newest_slot(path) -> str:
    with h5py.File(path, "r") as f:
        return max(("slot0", "slot1"), key=lambda s: f[f"checkpoint/{s}/meta"][1])


def flip(path, name, bit=3):
    """Flip one bit of the first element of dataset ``name`` (a valid entry: row 0, node 0; the step
    of a checkpoint's counters)."""
    with h5py.File(path, "r+") as f:
        d = f[name]
        values = d[()]
        flat = values.reshape(-1).view(np.uint64 if values.dtype.itemsize == 8 else np.uint8)
        flat[1 if name.endswith("/meta") else 0] ^= np.array(1 << bit, dtype=flat.dtype)
        d[()] = values


def problems(path, resuming=False):
    with h5py.File(path, "r") as f:
        return CaseStore.open(f).problems(resuming=resuming)


DATA = [f"timeseries/{n}" for n in SERIES] + [f"snapshots/{n}" for n in SNAPSHOT_RECORDS]
SLOT = [*State.ARRAYS, "scalars", "meta"]


@pytest.mark.parametrize("name", DATA + [f"checkpoint/newest/{n}" for n in SLOT]
                         + [f"checkpoint/older/{n}" for n in SLOT])
def test_a_flipped_bit_in_any_dataset_of_a_finished_case_is_named(files, tmp_path, name):
    path = tmp_path / "copy.h5"
    shutil.copy(files / "whole.h5", path)
    assert problems(path) == []
    newest = newest_slot(path)
    name = name.replace("newest", newest).replace("older", "slot0" if newest == "slot1" else "slot1")
    flip(path, name)
    found = problems(path)
    assert f"{name} fails its checksum" in found, found
    assert [p for p in found if "checksum" in p] == [f"{name} fails its checksum"]


@pytest.mark.parametrize("name", ["timeseries/digest", "snapshots/digest", "checkpoint/slot0/digest"])
def test_a_flipped_bit_in_a_checksum_is_caught_too(files, tmp_path, name):
    path = tmp_path / "copy.h5"
    shutil.copy(files / "whole.h5", path)
    flip(path, name)
    assert any("fails its checksum" in p for p in problems(path))


def test_a_resumed_run_passes_over_a_damaged_checkpoint_and_ends_bitwise_identical(files, tmp_path, caplog):
    path = tmp_path / "cut.h5"
    shutil.copy(files / "cut.h5", path)
    newest = newest_slot(path)
    flip(path, f"checkpoint/{newest}/psi")
    assert f"checkpoint/{newest}/psi fails its checksum" in problems(path)
    assert problems(path, resuming=True) == []               # the other slot passes: resumable
    with caplog.at_level(logging.WARNING, logger="hpcves"):
        assert resume_in_process(path).status == FINISHED
    assert any(f"checkpoint {newest}" in r.message and "passed over" in r.message for r in caplog.records)
    same_case_files(files / "whole.h5", path, checkpoints=True)
    assert problems(path) == []        # the damaged slot was the older one and has been written again


def test_with_both_checkpoints_damaged_a_resume_is_refused_in_one_line(files, tmp_path):
    path = tmp_path / "cut.h5"
    shutil.copy(files / "cut.h5", path)
    flip(path, "checkpoint/slot0/theta")
    flip(path, "checkpoint/slot1/scalars")
    assert any("fails its checksum" in p for p in problems(path, resuming=True))
    before = path.read_bytes()
    result = subprocess.run(HPCVES + ["run", "--resume", str(path)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "damaged, not resumed" in lines[0] and "checkpoint/slot0/theta fails its checksum" \
        in lines[0] and "Traceback" not in result.stderr, result.stderr
    assert path.read_bytes() == before


SUMS = dict(name="sums", psi=None)      # the tiny test campaign over two shear rates


def test_status_check_and_analyze_name_the_damaged_case_and_dataset_and_exit_2(tmp_path):
    output = tmp_path / "sums.h5"
    assert run_campaign(study_from_toml(tiny_study(output, **SUMS)), output).exit_status == 0
    with h5py.File(output, "r+") as f:
        case = case_view(f, "0001")
        values = case["timeseries/theta"]
        values.view(np.uint64)[5] ^= np.uint64(1)                 # one bit of the last mantissa place
        case["timeseries/theta"] = values
    plain = subprocess.run(HPCVES + ["status", str(output)], capture_output=True, text=True, timeout=300)
    check = subprocess.run(HPCVES + ["status", "--check", str(output)], capture_output=True, text=True, timeout=300)
    assert check.returncode == 2, (check.stdout, check.stderr)
    said = check.stdout + check.stderr
    assert "0001" in said and "timeseries/theta fails its checksum" in said
    assert "checksum" not in plain.stdout + plain.stderr             # plain status reads no data
    analyzed = subprocess.run(HPCVES + ["analyze", str(output), "--out", str(tmp_path / "a")], capture_output=True,
                              text=True, timeout=300)
    assert analyzed.returncode == 2, (analyzed.stdout, analyzed.stderr)
    assert "timeseries/theta fails its checksum" in analyzed.stdout + analyzed.stderr
    with pytest.raises(FileFormatError, match="case 0001: timeseries/theta fails its checksum"):
        run_campaign(study_from_toml(tiny_study(output, **SUMS)), output, resume=True)


@pytest.mark.parametrize("record", ["timeseries/centroid", "snapshots/psi", "snapshots/t", "checkpoint/newest/prev_psi",
                                    "checkpoint/newest/scalars"])
def test_a_flipped_bit_in_each_kind_of_record_of_a_packed_block_is_named(tmp_path, record):
    """Campaign format 3 packs a block's series, snapshot fields and checkpoint arrays into one array
    each: a bit flipped in one record's part of it is named as that record (CaseStore.problems; a data
    record by CampaignFile.damaged too, what status --check, analyze and --resume report)."""
    from hpcves.campaign.file import CampaignFile
    from hpcves.run.store import open_file

    output = tmp_path / "sums.h5"
    study = study_from_toml(tiny_study(output, **SUMS))
    assert run_campaign(study, output).exit_status == 0
    with h5py.File(output, "r+") as f:
        case = case_view(f, "0000")
        newest = max(("slot0", "slot1"), key=lambda s: case[f"checkpoint/{s}/meta"][1])
        name = record.replace("newest", newest)
        assert case.path(name).endswith({"timeseries": "timeseries/series", "snapshots/psi": "snapshots/fields",
                                         "snapshots/t": "snapshots/t", "checkpoint/newest/prev_psi": f"{newest}/arrays",
                                         "checkpoint/newest/scalars": f"{newest}/scalars"}.get(
                                             record.split("/")[0] if record.startswith("time") else record))
        values = case[name]
        values.reshape(-1).view(np.uint64)[1] ^= np.uint64(1 << 40)
        case[name] = values
    with open_file(output, "r") as h5:
        campaign = CampaignFile(h5)
        assert campaign.store("0000").problems() == [f"{name} fails its checksum"]
        damaged = dict(campaign.damaged(study))        # as --resume sees it: the other slot would do
    assert damaged == ({} if record.startswith("checkpoint") else {"0000": [f"{name} fails its checksum"]})


@pytest.mark.parametrize("history", ["one run", "appended in batches", "truncated then appended",
                                     "resumed mid-series"])
@pytest.mark.parametrize("layout", ["group", "packed row"])
def test_the_checksums_written_at_the_end_are_those_of_the_bytes_stored(tmp_path, history, layout):
    """An ended case's checksums come from the rows its writer appended (a running BLAKE2b) or, where
    the writer did not append every row from the first on, from a read-back: either way they are
    digest() of the valid part as stored -- in a group of its own and as a row of a block whose records
    are packed (campaign format 3: a series is a column of timeseries/series)."""
    from hpcves.config import case_to_toml
    from hpcves.run.blocks import Blocks
    from hpcves.run.store import digest

    case = case_from_toml(CASE)
    rng = np.random.default_rng(5)

    def rows(k):
        return [{name: (rng.normal(size=2) if name == "centroid" else rng.normal()) for name in SERIES}
                for _ in range(k)]

    def snaps(k, width):
        return [{"t": rng.normal(), "shift": rng.normal(),
                 **{name: rng.normal(size=width) for name in SNAPSHOT_RECORDS if name not in ("t", "shift")}}
                for _ in range(k)]

    def new_store(f, create):
        if layout == "group":
            return CaseStore.create(f, case) if create else CaseStore.open(f)
        if create:
            f.attrs["format_version"] = 3
            Blocks.create(f).add([case])
        return Blocks(f).store(0, 0, case_to_toml(case), "/cases/0000")

    path = tmp_path / "case.h5"
    with h5py.File(path, "w") as f:
        store = new_store(f, create=True)
        assert (store._place.column("timeseries/theta") is None) == (layout == "group")
        width = store.width
        store.append_samples(rows(3))
        store.append_snapshots(snaps(2, width))
        if history != "one run":
            store.append_samples(rows(4))
            store.append_snapshots(snaps(1, width))
        if history == "truncated then appended":
            store.truncate(5, 1)
            store.append_samples(rows(2))
            store.append_snapshots(snaps(2, width))
        if history == "resumed mid-series":
            store = new_store(f, create=False)  # a new writer: the rows before it were written by another
            store.truncate(6, 2)
            store.append_samples(rows(3))
            store.append_snapshots(snaps(1, width))
        store.set_status(FINISHED)
    with h5py.File(path, "r") as f:
        store = new_store(f, create=False)
        stored = np.concatenate([store._read("timeseries/digest"), store._read("snapshots/digest")])
        assert [int(d) for d in stored] == [digest(values) for _, values in store._records()]
        assert store.data_damage() == [] and store.n_samples == {"one run": 3, "appended in batches": 7,
                                                                  "truncated then appended": 7,
                                                                  "resumed mid-series": 9}[history]


# ---------------------------------------------------------------------- what a resume builds on (format 6)
def slot_counts(path, slot):
    with h5py.File(path, "r") as f:
        return tuple(int(v) for v in f[f"checkpoint/{slot}/meta"][2:])


def damage_row(path, name, row):
    """Flip one bit of row ``row`` (its first element) of record ``name`` of a case file."""
    with h5py.File(path, "r+") as f:
        values = f[name][()]
        values.reshape(len(values), -1).view(np.uint64)[row, 0] ^= np.uint64(1 << 7)
        f[name][()] = values


@pytest.mark.parametrize("name", ["timeseries/theta", "timeseries/centroid", "snapshots/psi", "snapshots/t"])
def test_a_resume_refuses_rows_damaged_before_both_checkpoints_instead_of_giving_them_fresh_checksums(
        files, tmp_path, name):
    """A resume of a case whose written series were damaged took them as they were, and the checksums
    written when it ended were of the damaged values (status --check then clean, the result other than
    the uninterrupted run's). Every checkpoint now carries the checksums of the rows it builds on."""
    path = tmp_path / "cut.h5"
    shutil.copy(files / "cut.h5", path)
    assert min(slot_counts(path, "slot0")[name.startswith("snap")],
               slot_counts(path, "slot1")[name.startswith("snap")]) >= 1
    damage_row(path, name, 0)                      # a row both checkpoints keep
    found = problems(path, resuming=True)
    assert any(p.startswith(f"{name} (the ") and "builds on) fails its checksum" in p for p in found), found
    before = path.read_bytes()
    result = subprocess.run(HPCVES + ["run", "--resume", str(path)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 2 and "damaged, not resumed" in result.stderr and name in result.stderr, \
        result.stderr
    assert path.read_bytes() == before


def test_rows_damaged_after_the_older_checkpoint_are_recomputed_from_it_and_the_end_is_bitwise(files, tmp_path,
                                                                                              caplog):
    path = tmp_path / "cut.h5"
    shutil.copy(files / "cut.h5", path)
    newest = newest_slot(path)
    older = "slot0" if newest == "slot1" else "slot1"
    kept, newer = slot_counts(path, older)[0], slot_counts(path, newest)[0]
    assert kept < newer
    damage_row(path, "timeseries/theta", kept)     # kept by the newer checkpoint only
    assert problems(path, resuming=True) == []     # the older one is sound: resumable
    with caplog.at_level(logging.WARNING, logger="hpcves"):
        assert resume_in_process(path).status == FINISHED
    assert any(f"checkpoint {newest}" in r.message and "timeseries/theta" in r.message for r in caplog.records)
    same_case_files(files / "whole.h5", path, checkpoints=True)
    assert problems(path) == []


def test_the_next_checkpoint_overwrites_the_slot_passed_over_not_the_one_resumed_from(files, tmp_path):
    """Resumed from the older slot because the newer failed its checksums, the run wrote its next
    checkpoint over the older one -- its only sound checkpoint, invalid while it was rewritten."""
    path = tmp_path / "cut.h5"
    shutil.copy(files / "cut.h5", path)
    newest = newest_slot(path)
    older = "slot0" if newest == "slot1" else "slot1"
    with h5py.File(path, "r") as f:
        kept = f[f"checkpoint/{older}"]["meta"][()].copy(), f[f"checkpoint/{older}"]["theta"][()].copy()
    flip(path, f"checkpoint/{newest}/theta")
    assert resume_in_process(path, stops=(20,)).status == INTERRUPTED     # before the next interval: one checkpoint
    with h5py.File(path, "r") as f:
        assert np.array_equal(f[f"checkpoint/{older}/meta"][()], kept[0])
        assert np.array_equal(f[f"checkpoint/{older}/theta"][()], kept[1], equal_nan=True)
    assert problems(path) == []


def without_rheology(g):
    """Case or block ``g`` (an open group) as hpcves wrote it before format 7: no rheology series, and
    their checksums out of the digests (a packed block's series array rewritten without their columns)."""
    from hpcves.run.blocks import quantities
    from hpcves.run.diagnostics import RHEOLOGY_SERIES
    from hpcves.run.store import RECORDS_SINCE, SNAPSHOT_RECORDS, series_of
    kept = len(series_of(RECORDS_SINCE))
    assert all(n not in RHEOLOGY_SERIES for n in series_of(RECORDS_SINCE))
    if "timeseries/series" in g:
        old = g["timeseries/series"]
        data, chunks, scales = old[()][..., :len(quantities(RECORDS_SINCE))], old.chunks, [d[0] for d in old.dims]
        del g["timeseries/series"]
        new = g["timeseries"].create_dataset("series", data=data, maxshape=(None, *data.shape[1:]),
                                              chunks=(1, *chunks[1:2], data.shape[2]), fillvalue=np.nan)
        for name in ("quantity", "long_name", "units"):
            values = g[f"timeseries/{name}"][:len(data[0, 0])]
            del g[f"timeseries/{name}"]
            g["timeseries"].create_dataset(name, data=values, dtype=h5py.string_dtype())
        g["timeseries/quantity"].make_scale("quantity")
        for axis, scale in enumerate([scales[0], scales[1], g["timeseries/quantity"]]):
            new.dims[axis].attach_scale(scale)
    else:
        for name in RHEOLOGY_SERIES:
            del g[f"timeseries/{name}"]
    digest = g["timeseries/digest"][..., :kept]
    del g["timeseries/digest"]
    g.create_dataset("timeseries/digest", data=digest, maxshape=(None, *digest.shape[1:]) if digest.ndim > 1 else None)
    for slot in ("slot0", "slot1"):
        if f"checkpoint/{slot}/records" in g:
            records = g[f"checkpoint/{slot}/records"][()]
            records = np.concatenate([records[..., :kept], records[..., -len(SNAPSHOT_RECORDS):]], axis=-1)
            del g[f"checkpoint/{slot}/records"]
            g.create_dataset(f"checkpoint/{slot}/records", data=records,
                             maxshape=(None, *records.shape[1:]) if records.ndim > 1 else None)


def downgrade_to_format_5(path, group="/"):
    """A case (or a block: ``group``) as hpcves wrote it before format 6: no rheology series (format
    7), no ``records`` in its slots."""
    with h5py.File(path, "r+") as f:
        g = f[group]
        without_rheology(g)
        g.attrs["format_version"] = 5
        for slot in ("slot0", "slot1"):
            del g[f"checkpoint/{slot}/records"]


def test_a_case_of_format_5_resumes_as_before_and_ends_bitwise(files, tmp_path):
    path = tmp_path / "cut.h5"
    shutil.copy(files / "cut.h5", path)
    downgrade_to_format_5(path)
    assert problems(path, resuming=True) == []
    assert resume_in_process(path).status == FINISHED
    same_case_files(files / "whole.h5", path)
    assert problems(path) == []


def test_a_campaign_with_blocks_of_format_5_resumes_and_grows(tmp_path):
    """Blocks keep the case format they were made in: a format-5 block resumes its cases and takes a
    grown study's new rows in its own layout; a new block is of format 6."""
    from hpcves.run.blocks import Blocks

    output = tmp_path / "sums.h5"
    text = tiny_study(output, name="sums", psi=None, t_end=0.1)
    assert run_campaign(study_from_toml(text), output, resume=False,
                        stop_flag=lambda: False).exit_status == 0
    downgrade_to_format_5(output, "blocks/0")
    grown = text.replace("shear_rate = [40, 80]", "shear_rate = [40, 80, 60]")
    assert run_campaign(study_from_toml(grown), output, resume=True).exit_status == 0
    with h5py.File(output, "r") as f:
        assert Blocks(f).version_of("0") == 5 and f["blocks/0/status"].shape[0] == 3
        assert "records" not in f["blocks/0/checkpoint/slot0"]
    assert subprocess.run(HPCVES + ["status", "--check", str(output)], capture_output=True,
                          timeout=300).returncode == 0
