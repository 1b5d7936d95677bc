"""The campaign HDF5 file: every case of a study in one file (docs/file-format.md).

    attrs      format = "hpcves-campaign", format_version, hpcves_version, name,
               fingerprint (Study.fingerprint), campaign_toml (the campaign
               file's text), campaign_toml_sha256 (its checksum; absent in files
               made before it existed), sweep_keys, n_cases
               mode ("grid", "search" or "refine")
    index/     case_id (n,) strings; one (n,) float64 dataset per swept key; cost (n,);
               formats 2, 3: block (n,) and row (n,), where each case lies, and config (n,), its
               TOML text;
               search (n,) int (the search -- or refinement -- of each case; -1 in a grid);
               chain studies: after (n,) strings, the case each starts from ("" for none) --
               all resizable: a search or refinement adds its cases stage by stage
    searches/  search files: one (n_searches,) dataset per swept key
    refinements/  refine files: one (n_refinements,) dataset per swept key that is not an axis
    blocks/<k>/  format 2 and 3: the cases of one shape as rows of arrays with a case dimension
               (run/blocks.py): status, message, traceback, progress, timeseries/ (preallocated,
               with a length counter), snapshots/, checkpoint/slot0|slot1 with a validity
               marker written last -- the datasets of a single run's file, one row a case;
               format 3 packs the series into one array, the snapshot fields into one, and
               the arrays of each checkpoint slot into one
    cases/<id>/  format 1: one case, laid out exactly as a single run (store.CaseStore), its
               parameters as attributes

The whole structure is created up front -- by rank 0 alone with serial HDF5,
in every I/O mode (campaign/structure.py, ``_change``) -- under a temporary name
that becomes the file's only once it is complete (atomic.py).
Afterwards only raw data are written in place, each case by the one rank
running it (independent I/O; attributes are never written again); a search
stage's cases are added to a copy that replaces the file (format 2: its
blocks grow by them, one resize per array).
"""
from __future__ import annotations

import hashlib
import tomllib
from dataclasses import dataclass

import h5py
import numpy as np

from hpcves.campaign.study import Study, study_from_toml
from hpcves.config import case_to_toml
from hpcves.files import faults
from hpcves.files.atomic import partial_path
from hpcves.files.lock import writer
from hpcves.run.blocks import BLOCKS, Blocks
from hpcves.run.stamp import Stamper
from hpcves.run.store import (
    HDF5_ERRORS,
    STATUS_NAMES,
    CaseStore,
    FileFormatError,
    attr_integer,
    attr_shown,
    attr_text,
    open_file,
    reading,
)
from hpcves.run.verdict import DAMAGED, classifier
from hpcves.version import __version__


def text_digest(text: str) -> str:
    """SHA-256 of a text's UTF-8 bytes, in hex (the stored study's checksum)."""
    return hashlib.sha256(text.encode()).hexdigest()


class BeingCreated(FileFormatError):
    """The campaign file does not exist yet: a running campaign is laying it out."""


class CreationInterrupted(FileFormatError):
    """The campaign file does not exist: its making was cut short (``--resume`` starts it again)."""

FORMAT = "hpcves-campaign"
#: the modes whose cases come stage by stage (a stage may be half-added when a crash cut it short)
STAGED_MODES = ("search", "refine")
#: 3: blocks whose records a run writes together are packed into one array each (run/blocks.py,
#: ``packing``); 2: cases as rows of blocks, a dataset a record; 1: a group per case (2 and 1 are read,
#: resumed and extended as such)
FORMAT_VERSION = 3
READS_VERSIONS = (1, 2, 3)
#: the layout new files get (tests set 1 to make files of the older layout, which this hpcves reads,
#: resumes and extends as such)
WRITES_VERSION = FORMAT_VERSION


class CampaignFile:
    """The cases of one study inside an open h5py File."""

    def __init__(self, h5):
        self.h5 = h5
        self.version = attr_integer(h5.attrs.get("format_version", FORMAT_VERSION))
        if self.version == 1:
            self._cases, self._blocks = h5["cases"], None
        else:
            self._cases, self._blocks = None, Blocks(h5)
        #: format 2: {case id: (index row, block, row)} and the index's config column (read when first needed)
        self._rows, self._configs = None, None
        #: the index's swept columns of the complete cases, read when first needed (:meth:`swept_disagree`)
        self._swept = None

    # ------------------------------------------------------------------ creation / opening
    @classmethod
    def create(cls, h5, study: Study) -> "CampaignFile":
        """Lay out the file and every case known yet (one process: rank 0, serial HDF5)."""
        a = h5.attrs
        a["format"] = FORMAT
        version = WRITES_VERSION
        a["format_version"] = version
        a["hpcves_version"] = __version__
        a["name"] = study.name
        a["fingerprint"] = study.fingerprint
        a["campaign_toml"] = study.source
        a["campaign_toml_sha256"] = text_digest(study.source)
        a["mode"] = study.mode
        a["sweep_keys"] = ",".join(study.sweep_keys)
        a["n_cases"] = 0
        index = h5.create_group("index")
        growing = {"shape": (0,), "maxshape": (None,), "chunks": (1024,)}
        index.create_dataset("case_id", dtype=f"S{study.id_width}", **growing)
        for key in study.sweep_keys:
            index.create_dataset(key, dtype="f8", **growing)
        index.create_dataset("cost", dtype="f8", **growing)
        index.create_dataset("search", dtype="i4", **growing)
        if version == 1:
            index.create_dataset("addresses", shape=(0, len(STATE)), maxshape=(None, len(STATE)),
                                 chunks=(1024, len(STATE)), dtype="u8")
        else:
            index.create_dataset("block", dtype="i4", **growing)
            index.create_dataset("row", dtype="i8", **growing)
            index.create_dataset("config", dtype=h5py.string_dtype(), **growing)
        if study.staged:
            verdicts = index.create_dataset("verdict", shape=(0, 2), maxshape=(None, 2), chunks=(1024, 2), dtype="f8")
            verdicts.attrs["classifier"] = classifier()
        if study.chain:
            index.create_dataset("after", dtype=f"S{study.id_width}", **growing)
        if study.search:
            searches = h5.create_group("searches")
            for key in study.sweep:
                searches.create_dataset(key, data=np.array([p[key] for p in study.searches], dtype="f8"))
        if study.refine:
            refinements = h5.create_group("refinements")
            for key in study.refinements[0]:
                refinements.create_dataset(key, data=np.array([p[key] for p in study.refinements], dtype="f8"))
        if version == 1:
            h5.create_group("cases")
        else:
            Blocks.create(h5)
        campaign = cls(h5)
        campaign.add_cases(study.cases)
        return campaign

    def grow(self, study: Study, new) -> None:
        """Make this the file of ``study``, a study grown from its own (campaign/growth.py): its
        fingerprint and text, its searches or refinements (the file's first, then the new ones),
        and its ``new`` cases laid out (one process: rank 0, on a copy that then replaces the file)."""
        for name, points in (("searches", study.searches), ("refinements", study.refinements)):
            if points:
                group = self.h5[name]
                for key in list(group):
                    del group[key]
                for key in (study.sweep if name == "searches" else points[0]):
                    group.create_dataset(key, data=np.array([p[key] for p in points], dtype="f8"))
        self.add_cases(new)
        self.h5.attrs["campaign_toml"] = study.source
        self.h5.attrs["campaign_toml_sha256"] = text_digest(study.source)
        self.h5.attrs["fingerprint"] = study.fingerprint

    def add_cases(self, cases, source: str | None = None) -> None:
        """Lay out new cases and append them to the index (one process: rank 0); with ``source``,
        the campaign file's text replaces the stored one where it differs (a refinement continued
        with a larger ``max_cases``: the fingerprint leaves the budget out).

        Order matters for a crash in the middle: the groups come first, the
        index next, the ``n_cases`` attribute last, so a file whose groups
        outnumber ``n_cases`` is recognisably one with a half-added stage
        (:meth:`drop_partial_stage`).
        """
        cases = list(cases)
        if not cases:
            return
        columns = {}
        if self._blocks is not None:
            places = self._blocks.add([c.case for c in cases], self.h5["index/case_id"].shape[0])
            faults.point("case-laid-out")
            columns = {"block": [b for b, _ in places], "row": [r for _, r in places],
                       "config": [case_to_toml(c.case) for c in cases]}
        else:
            stamper = Stamper(self._cases)
            addresses = []
            for c in cases:
                group = stamper.lay_out(c.case_id, c.case, {"case_id": c.case_id})
                addresses.append(_addresses(group))
                faults.point("case-laid-out")
        index = self.h5["index"]
        start = index["case_id"].shape[0]
        stop = start + len(cases)
        if "addresses" in index:
            index["addresses"].resize((stop, len(STATE)))
            index["addresses"][start:stop] = np.array(addresses, dtype=np.uint64)
        if "verdict" in index:
            index["verdict"].resize((stop, 2))
            index["verdict"][start:stop] = np.array([[-1.0, np.nan]] * len(cases))
        columns.update({"case_id": [c.case_id.encode() for c in cases], "cost": [c.cost for c in cases],
                        "search": [c.search for c in cases]})
        columns.update({k: [c.swept[k] for c in cases] for k in self.sweep_keys})
        if "after" in index:
            columns["after"] = [c.after.encode() for c in cases]
        for key, values in columns.items():
            dataset = index[key]
            dataset.resize((stop,))
            dataset[start:stop] = np.array(values, dtype=object if key == "config" else dataset.dtype)
        self._rows, self._swept = None, None
        if source is not None and attr_text(self.h5.attrs.get("campaign_toml", "")) != source:
            self.h5.attrs["campaign_toml"] = source
            self.h5.attrs["campaign_toml_sha256"] = text_digest(source)
        self.h5.attrs["n_cases"] = stop

    @staticmethod
    def has_partial_stage(h5) -> bool:
        """Whether a search file holds the cases of a stage whose adding was cut short: more rows in
        index/ (blocks layout) or more case groups (format 1) than ``n_cases`` says."""
        if attr_text(h5.attrs.get("mode", "")) != "search":
            return False
        n = int(h5.attrs.get("n_cases", -1))
        if BLOCKS in h5:
            return "index" in h5 and h5["index/case_id"].shape[0] > n
        return len(h5.get("cases", ())) != n

    @staticmethod
    def drop_partial_stage(h5) -> int:
        """Remove the cases of a stage whose adding was cut short (search files; serial access).

        Returns the number of case groups removed.
        """
        n = int(h5.attrs["n_cases"])
        if BLOCKS in h5:
            index = h5["index"]
            extra = max(0, index["case_id"].shape[0] - n)
            used = {}
            for block, row in zip(index["block"][:n], index["row"][:n]):
                used[int(block)] = max(used.get(int(block), 0), int(row) + 1)
            Blocks(h5).shrink(used)
        else:
            extra = [case_id for case_id in h5["cases"] if int(case_id) >= n]
            for case_id in extra:
                del h5["cases"][case_id]
            extra = len(extra)
        for dataset in h5["index"].values():
            if dataset.shape[0] > n:
                dataset.resize((n, *dataset.shape[1:]))
        return extra

    @classmethod
    def check(cls, h5, where: str) -> "CampaignFile":
        """Open an existing campaign file, refusing anything else with a clear message."""
        fmt = attr_text(h5.attrs.get("format", ""))
        if fmt == "hpcves-case":
            raise FileFormatError(f"{where}: a single-run file (hpcves run), not a campaign file")
        if fmt != FORMAT:
            raise FileFormatError(f"{where}: not an hpcves campaign file (no format = {FORMAT!r} attribute)")
        written = h5.attrs.get("format_version", -1)
        version = attr_integer(written)
        if version not in READS_VERSIONS:
            raise FileFormatError(f"{where}: campaign format version {attr_shown(written)}, this hpcves reads "
                                  + " and ".join(map(str, READS_VERSIONS)))
        mode = attr_text(h5.attrs.get("mode", "grid"))
        if mode not in ("grid", *STAGED_MODES):
            raise FileFormatError(f"{where}: mode {mode!r} is not a kind of campaign (grid, "
                                  + ", ".join(STAGED_MODES) + ")")
        missing = [k for k in ("index", "cases" if version == 1 else BLOCKS) if k not in h5]
        if missing:
            raise FileFormatError(f"{where}: incomplete campaign file, missing {', '.join(missing)}")
        n = attr_integer(h5.attrs.get("n_cases", -1))
        if n is None or n < 0:
            raise FileFormatError(f"{where}: its header's case count {h5.attrs.get('n_cases')} is not a count")
        staged = mode in STAGED_MODES
        held = len(h5["cases"]) if version == 1 else h5["index/case_id"].shape[0]
        if held != n and not (staged and held > n):                          # a half-added stage
            raise FileFormatError(f"{where}: holds {held} cases, its header says {n} "
                                  "(creation was interrupted?)")
        keys = [k for k in attr_text(h5.attrs.get("sweep_keys", "")).split(",") if k]
        for key in ("case_id", "cost", *keys, *(("block", "row", "config") if version >= 2 else ())):
            if key not in h5["index"] or h5["index"][key].shape[:1] < (n,):
                raise FileFormatError(f"{where}: index/{key} is missing or shorter than the {n} cases")
        return cls(h5)

    # ------------------------------------------------------------------ contents
    @property
    def name(self) -> str:
        return attr_text(self.h5.attrs["name"])

    @property
    def fingerprint(self) -> str:
        return attr_text(self.h5.attrs.get("fingerprint", ""))

    @property
    def mode(self) -> str:
        """"grid" (every case known up front), "search" (critical-shear searches) or "refine" (regime
        boundaries refined): the last two add their cases stage by stage."""
        return attr_text(self.h5.attrs.get("mode", "grid"))

    def searches_of_cases(self) -> list[int]:
        """The search (or refinement) each case belongs to (-1 in a grid study), in id order."""
        index = self.h5["index"]
        n = int(self.h5.attrs["n_cases"])
        return [int(v) for v in index["search"][:n]] if "search" in index else [-1] * n

    @property
    def sweep_keys(self) -> list[str]:
        keys = attr_text(self.h5.attrs.get("sweep_keys", ""))
        return [k for k in keys.split(",") if k]

    @property
    def case_ids(self) -> list[str]:
        """Every complete case (a search's half-added stage beyond ``n_cases`` left out)."""
        n = int(self.h5.attrs["n_cases"])
        return [attr_text(i) for i in self.h5["index/case_id"][:n]]

    def chain_links(self) -> dict[str, str]:
        """{case id: the case whose end state it starts from} of a chain study's linked cases ({} else)."""
        index = self.h5["index"]
        if "after" not in index:
            return {}
        n = int(self.h5.attrs["n_cases"])
        return {case_id: attr_text(after) for case_id, after in zip(self.case_ids, index["after"][:n])
                if attr_text(after)}

    def stored_text(self, where: str) -> str:
        """The text of the study the file was made from (``campaign_toml``: what replays its searches,
        names its starts and holds its [analysis] thresholds), checked against its checksum -- in a file
        made before the checksum existed, against the file's fingerprint (:meth:`stored_study`)."""
        text = attr_text(self.h5.attrs.get("campaign_toml", ""))
        checksum = self.h5.attrs.get("campaign_toml_sha256")
        if checksum is None:
            self.stored_study(where)
        elif attr_text(checksum) != text_digest(text):
            raise FileFormatError(f"{where}: its stored study (campaign_toml) fails its checksum: edited or "
                                  "damaged; what the file's searches, starts and thresholds are is unknown")
        return text

    def stored_study(self, where: str) -> Study:
        """The study the file was made from, parsed from its stored text (:meth:`stored_text`); where the
        file keeps no checksum of the text, the study's fingerprint must be the file's."""
        text = attr_text(self.h5.attrs.get("campaign_toml", ""))
        checksum = self.h5.attrs.get("campaign_toml_sha256")
        if checksum is not None:
            self.stored_text(where)
        study = study_from_toml(text, source=f"{where}: campaign_toml", default_name=self.name)
        if checksum is None and study.fingerprint != self.fingerprint:
            raise FileFormatError(f"{where}: its stored study (campaign_toml) is not the study of its fingerprint: "
                                  "edited or damaged; what the file's searches, starts and thresholds are is unknown")
        return study

    def swept_disagree(self, i: int, case) -> list[str]:
        """Where the index's swept values of case ``i`` (what tables, diagrams and growth read) are not
        its parameters (what it ran: ``case``, from its config): one was edited or damaged."""
        if self._swept is None:               # read once: a check of every case reads them all
            n = int(self.h5.attrs["n_cases"])
            self._swept = {key: self.h5["index"][key][:n] for key in self.sweep_keys}
        found = []
        for key, column in self._swept.items():
            if key == "start" or not hasattr(case.physics, key):
                continue
            listed, ran = float(column[i]), float(getattr(case.physics, key))
            if listed != ran and not (listed != listed and ran != ran):
                found.append(f"index/{key} lists {listed:g}, its config ran {key} = {ran:g} (edited or damaged)")
        return found

    def start_names(self) -> list[str]:
        """The names of the study's [starts], in the order swept (from the stored campaign file)."""
        try:
            table = tomllib.loads(attr_text(self.h5.attrs.get("campaign_toml", ""))).get("starts", {})
        except tomllib.TOMLDecodeError:
            return []
        return list(table) if isinstance(table, dict) else []

    def state(self, case_id: str) -> tuple[int, float]:
        """(status, wall seconds) of one case."""
        if self._blocks is not None:
            store = self.store(case_id)
            return store.status, float(store.progress[2])
        found = _summary(self._cases, case_id)
        if found is None:                    # the usual way, which says what is wrong
            group = self._cases[case_id]
            return int(group["status"][()]), float(group["progress"][2])
        return found[1], float(found[0][2])

    def _verdicts(self):
        """index/verdict where the file keeps verdicts and this hpcves's classifier computed them, else None."""
        dataset = self.h5["index"].get("verdict")
        if dataset is None or attr_text(dataset.attrs.get("classifier", "")) != classifier():
            return None
        return dataset

    def stored_verdicts(self) -> dict[str, tuple[float, float]]:
        """{case id: (verdict code, the case's wall seconds when classified)} of the cases whose verdict
        a staged campaign stored (index/verdict), computed by this hpcves's classifier; {} else."""
        dataset = self._verdicts()
        if dataset is None:
            return {}
        ids = self.case_ids
        values = dataset[:len(ids)]
        return {case_id: (float(code), float(wall)) for case_id, (code, wall) in zip(ids, values) if code >= 0}

    def store_verdicts(self, found: dict[str, tuple[int, float]]) -> None:
        """Write {case id: (verdict code, wall seconds)} into index/verdict, in place (rank 0, between
        stages: raw data of a dataset only rank 0 writes; nothing where the file keeps no verdicts or
        another classifier's)."""
        dataset = self._verdicts() if found else None
        if dataset is None:
            return
        rows = {case_id: i for i, case_id in enumerate(self.case_ids)}
        at = sorted((rows[c], code, wall) for c, (code, wall) in found.items() if c in rows)
        if not at:
            return
        first, last = at[0][0], at[-1][0] + 1
        values = dataset[first:last]              # one read and one write (h5py's ~0.1 ms a row otherwise)
        for i, code, wall in at:
            values[i - first] = (float(code), float(wall))
        dataset[first:last] = values

    def _index(self) -> dict[str, tuple[int, int, int]]:
        """{case id: (index row, block, row)} of every complete case (format 2), read once."""
        if self._rows is None:
            index = self.h5["index"]
            ids = self.case_ids
            n = len(ids)
            self._rows = {case_id: (i, int(b), int(r))
                          for i, (case_id, b, r) in enumerate(zip(ids, index["block"][:n], index["row"][:n]))}
            self._configs = None
        return self._rows

    def store(self, case_id: str) -> CaseStore:
        """The case ``case_id``, to read or write (FileFormatError where it is not in the file)."""
        if self._blocks is None:
            return CaseStore.open(self._cases[case_id], where=f"cases/{case_id}")
        where = f"/cases/{case_id}"
        found = self._index().get(case_id)
        if found is None:
            raise FileFormatError(f"{where}: no such case in the index")
        i, block, row = found
        if self._configs is None:
            self._configs = self.h5["index/config"][:len(self._rows)]
        return self._blocks.store(block, row, attr_text(self._configs[i]), where, {"case_id": case_id})

    def _by_block(self) -> dict[int, tuple[list[str], np.ndarray]]:
        """{block: (its case ids, their rows)} (format 2)."""
        out = {}
        for case_id, (_, block, row) in self._index().items():
            ids, rows = out.setdefault(block, ([], []))
            ids.append(case_id)
            rows.append(row)
        return {b: (ids, np.array(rows, dtype=np.int64)) for b, (ids, rows) in out.items()}

    def _block_values(self, names) -> dict[str, tuple]:
        """{case id: (one value per name in ``names``)} read a block at a time (format 2); a block whose
        arrays cannot be read whole is read a case at a time, and a case that cannot be read is left out
        (its store says why)."""
        found = {}
        for block, (ids, rows) in self._by_block().items():
            try:
                group = self.h5[f"{BLOCKS}/{block}"]
                columns = [group[name][:] for name in names]
                for case_id, row in zip(ids, rows):
                    found[case_id] = tuple(column[row] for column in columns)
            except (*HDF5_ERRORS, ValueError):
                for case_id in ids:
                    try:
                        store = self.store(case_id)
                        found[case_id] = tuple(store._read(name) for name in names)
                    except (FileFormatError, *HDF5_ERRORS):
                        pass
        return found

    def statuses(self) -> dict[str, int]:
        """{case id: status} of every case, read through h5py's low-level API (its high-level lookup
        costs ~0.1 ms a case, and a staged campaign asks between its stages); a case whose status
        cannot be read that way is read the usual way, which says what is wrong."""
        if self._blocks is not None:
            found = self._block_values(("status",))
            return {case_id: int(found[case_id][0]) if case_id in found else self.store(case_id).status
                    for case_id in self.case_ids}
        found, cases, buffer = {}, self._cases.id, np.empty((), dtype=np.int64)
        for case_id in self.case_ids:
            try:
                dataset = h5py.h5d.open(h5py.h5g.open(cases, case_id.encode()), b"status")
                if dataset.shape != () or dataset.dtype.kind not in "iu":
                    raise ValueError
                dataset.read(h5py.h5s.ALL, h5py.h5s.ALL, buffer, mtype=h5py.h5t.NATIVE_INT64)
                found[case_id] = int(buffer)
            except (*HDF5_ERRORS, ValueError):
                found[case_id] = int(self._cases[case_id]["status"][()])
        return found

    def damaged(self, study: Study) -> list[tuple[str, list[str]]]:
        """(case id, problems) of every case whose data are missing, misshapen or inconsistent
        (CaseStore.problems, as a resumed run sees them: a checkpoint that fails its checksums is passed
        over where the other one passes), checked against the study's own case; empty for a sound file."""
        found = []
        index = self.h5["index"]
        n = int(self.h5.attrs["n_cases"])
        short = [k for k in index if index[k].shape[0] < n]
        if short:
            return [("index", [f"index/{k} holds {index[k].shape[0]} rows for {n} cases" for k in short])]
        expected = {c.case_id: c.case for c in study.cases}
        for i, case_id in enumerate(self.case_ids):
            try:
                store = self.store(case_id)
            except (FileFormatError, *HDF5_ERRORS) as exc:
                found.append((case_id, [str(exc).split(": ", 1)[-1]]))
                continue
            problems = store.problems(expected.get(case_id), resuming=True)
            if not problems:
                problems = self.swept_disagree(i, store.case)
            if problems:
                found.append((case_id, problems))
        return found

    def table(self, check: bool = False, addresses: bool = False) -> list[dict]:
        """One row per case: id, swept values, status, t, t_end, wall, steps/s, message; with
        ``addresses``, read at their addresses (StateReader: a file opened with HDF5's default, POSIX
        driver only -- under mpio the handle is no file descriptor, and asking for it is collective).

        A case whose status or progress cannot be read, or holds an unknown status -- with ``check``:
        whose data fail CaseStore.problems -- is shown with status "damaged" and what is wrong as its
        message.
        """
        rows = []
        keys = self.sweep_keys
        n = int(self.h5.attrs["n_cases"])
        swept = {k: self.h5["index"][k][:n] for k in keys}
        links = self.chain_links()
        starts = self.start_names() if "start" in keys else []
        case_ids = self.case_ids
        fast = StateReader(self.h5, case_ids if addresses and self._blocks is None else [])
        blocked = self._block_values(("progress", "status", "message")) if self._blocks is not None else {}
        for i, case_id in enumerate(case_ids):
            values = {k: float(swept[k][i]) if i < len(swept[k]) else float("nan") for k in keys}
            if starts and 0 <= values["start"] < len(starts):
                values["start"] = starts[int(values["start"])]
            try:
                found = blocked.get(case_id)
                if self._blocks is not None and found is None:
                    store = self.store(case_id)
                    found = store.progress, store.status, store._read("message")[()]
                if found is not None:
                    found = found[0], int(found[1]), bytes(found[2])
                elif fast.fd is not None:           # the case's group must open: an unreadable one is damaged
                    h5py.h5g.open(self._cases.id, case_id.encode())
                    found = fast.read(i)
                if found is None:
                    found = _summary(self._cases, case_id)
                if found is None:            # the usual way, which says what is wrong
                    g = self._cases[case_id]
                    found = g["progress"][:], int(g["status"][()]), bytes(g["message"][()])
                progress, status, message = found
                t, t_end, wall, rate = (float(v) for v in progress)
                message = message.decode(errors="replace")
                name = STATUS_NAMES[status] if status in STATUS_NAMES else DAMAGED
                if name == DAMAGED:
                    message = f"status {status} is not a status"
                elif check:
                    store = self.store(case_id)
                    problems = store.problems() or self.swept_disagree(i, store.case)
                    if problems:
                        name, message = DAMAGED, "; ".join(problems[:2])
            except (FileFormatError, *HDF5_ERRORS) as exc:
                t = t_end = wall = rate = float("nan")
                name, message = DAMAGED, f"unreadable ({str(exc).strip().splitlines()[0] if str(exc) else exc})"
            row = {"case": case_id, **values, "status": name, "t": t, "t_end": t_end, "wall": wall,
                   "steps_per_second": rate, "message": message}
            if links:
                row["after"] = links.get(case_id, "")
            rows.append(row)
        return rows


#: what ``status`` reads of each case: (dataset, shape, numpy kind); index/addresses holds where
#: their bytes lie in the file, in this order
STATE = (("progress", (4,), "f"), ("status", (), "i"), ("message", (), "S"))


def _addresses(group) -> list[int]:
    """The file offsets of a case's STATE datasets' bytes (contiguous, allocated when laid out)."""
    return [h5py.h5d.open(group.id, name.encode()).get_offset() for name, _, _ in STATE]


def _summary(cases, case_id: str) -> tuple | None:
    """(progress, status, message bytes) of a case through h5py's low-level API -- a high-level lookup
    costs ~50 us, and ``status`` of 20 000 cases spent 6 of its 7 s on them -- or None where a dataset is
    not as laid out (missing, misshapen: the caller reads again the usual way, which says what is wrong)."""
    try:
        group = h5py.h5g.open(cases.id, case_id.encode())
        out = []
        for name, shape, kind in STATE:
            dataset = h5py.h5d.open(group, name.encode())
            if dataset.shape != shape or dataset.dtype.kind != kind:
                return None
            buffer = np.empty(shape, dtype=dataset.dtype)
            dataset.read(h5py.h5s.ALL, h5py.h5s.ALL, buffer)
            out.append(buffer)
    except HDF5_ERRORS:
        return None
    return out[0], int(out[1]), bytes(out[2][()])


class StateReader:
    """Each case's STATE of a format-1 file read from the bytes at its recorded addresses (index/addresses), with one
    ``pread`` each instead of opening three datasets (~80 us a case: 1.6 s of ``status`` at 20 000).

    The bytes read are those HDF5 reads: a contiguous dataset's data never move once allocated. A file
    rewritten by another tool (h5repack) moves them, so the addresses are trusted only where those of
    a sample of cases (first, last and every eighth of the way) agree with HDF5's, with the same types;
    else, or in files without the index (before it existed), :meth:`read` returns None and the caller
    opens the datasets.
    """

    SAMPLES = 8

    def __init__(self, h5, case_ids: list[str]):
        self.fd, self.dtypes, self.addresses = None, None, None
        index = h5["index"]
        n = len(case_ids)
        if "addresses" not in index or index["addresses"].shape[0] < n or not n:
            return
        addresses = index["addresses"][:n]
        try:
            fd = h5.id.get_vfd_handle()
            dtypes = None
            for i in sorted({0, n - 1, *range(0, n, max(1, n // self.SAMPLES))}):
                group = h5["cases"][case_ids[i]]
                found = []
                for (name, shape, kind), address in zip(STATE, addresses[i]):
                    dataset = group[name]
                    if (dataset.shape != shape or dataset.dtype.kind != kind
                            or dataset.id.get_offset() != int(address)):
                        return
                    found.append(dataset.dtype)
                if dtypes not in (None, found):
                    return
                dtypes = found
        except HDF5_ERRORS:
            return
        self.fd, self.dtypes, self.addresses = int(fd), dtypes, addresses

    def read(self, i: int) -> tuple | None:
        """(progress, status, message bytes) of case ``i``, or None (read it through HDF5)."""
        import os

        if self.fd is None:
            return None
        out = []
        for (name, shape, kind), dtype, address in zip(STATE, self.dtypes, self.addresses[i]):
            size = dtype.itemsize * int(np.prod(shape))
            raw = os.pread(self.fd, size, int(address))
            if len(raw) != size:
                return None
            out.append(np.frombuffer(raw, dtype=dtype).reshape(shape))
        return out[0], int(out[1]), bytes(out[2][()])


@dataclass(frozen=True)
class Table:
    """What ``hpcves status`` shows of a campaign file: its name, one row per case, who writes it."""

    name: str
    rows: list
    writer: str | None          # "pid ... on host, since ..." of the campaign writing it now, or None


def read_table(path, check: bool = False) -> Table:
    """The cases of a campaign file, read without locking (a campaign may be writing it).

    A file that does not exist yet but is being made (``<file>.partial`` and a campaign holding the
    lock) or whose making was cut short is refused with a message that says so.
    """
    import os

    path = os.fspath(path)
    if not os.path.exists(path) and os.path.exists(partial_path(path)):
        holder = writer(path)
        if holder is not None:
            raise BeingCreated(f"{path}: being created by a campaign ({holder}); it appears once "
                                  "every case is laid out")
        raise CreationInterrupted(f"{path}: its creation was interrupted (only {partial_path(path).name} is left); "
                              "hpcves campaign --resume starts it again")
    with open_file(path, "r", locking=False) as h5, reading(str(path)):
        campaign = CampaignFile.check(h5, str(path))
        if check:
            campaign.stored_text(str(path))
        return Table(campaign.name, campaign.table(check, addresses=True), writer(path))
