"""HDF5 storage of one case: parameters, time series, snapshots, checkpoints.

A case lives in an HDF5 group -- the file's root for ``hpcves run``, one
``cases/<id>`` group per case in a campaign file of format 1 -- or is one row of
the same datasets with a leading case dimension (campaign format 2: run/blocks.py;
:class:`CaseStore` reads and writes either through its place). Layout (see
docs/file-format.md):

    attrs          format = "hpcves-case", format_version, hpcves_version,
                   config (the full case as TOML), one attribute per parameter
                   ("physics.shear_rate", ...), N, capacities
    status         int8 scalar: 0 pending, 1 running, 2 finished, 3 failed, 4 interrupted
    message        fixed-length string: failure reason / last note
    traceback      fixed-length string: the traceback of a case that raised (absent in
                   files written before it existed; readers treat that as empty)
    progress       float64 [t, t_end, wall_seconds, steps_per_second], wall summed
                   over every call that advanced the case
    decision       float64 [regime code, t, step]: what stopped a run with
                   run.until_decided (decision.py; code 0: not decided) -- absent in
                   files written before it existed
    timeseries/    one preallocated dataset per series (NaN-filled), ``length``
                   counts the valid rows; centroid has shape (n, 2)
    snapshots/     t, shift and one (n, N) dataset per field; ``length`` counts
    checkpoint/    slot0/, slot1/: the solver State; each has ``meta`` =
                   [valid, step, n_samples, n_snapshots] and ``digest``, the checksum of
                   each array, the scalars and meta[1:] (format 5), and ``records``, the
                   checksums of the series and snapshot rows it builds on -- the first
                   n_samples of each series, the first n_snapshots of each snapshot
                   record, in the order of timeseries/digest then snapshots/digest (format 6)
    timeseries/digest, snapshots/digest
                   the checksums of the valid part of every series and snapshot
                   field, written when the case ends (format 5)

Everything that changes during a run is a dataset written in place (never an
attribute, never a resize): that keeps the writes independent in parallel
HDF5, and writes of raw data to preallocated space are the safest thing to be
doing when a process dies. A checkpoint goes to the slot *not* holding the
newest valid one: its ``meta`` is marked invalid first, the state written,
flushed, then marked valid -- so a crash in the middle leaves the previous
checkpoint intact and recognisably the newest valid one. Its checksums are
written before it is marked valid; a slot that fails them -- or whose series and
snapshots, the rows a resume keeps, fail theirs -- is passed over for the other
one when a run resumes (:meth:`CaseStore.read_checkpoint`), and written first.
"""
from __future__ import annotations

import math

import numpy as np

from hpcves.errors import FileFormatError
from hpcves.model.params import Case
from hpcves.run.checkpoints import CaseCheckpoints
from hpcves.run.checksums import digest
from hpcves.run.decision import REGIMES_BY_CODE
from hpcves.run.diagnostics import OPTIONAL_SERIES, SNAPSHOT_FIELDS
from hpcves.run.h5files import (
    HDF5_ERRORS,
    OBJECT_FORMAT,
    _first_line,
    _writes,
    attr_integer,
    attr_shown,
    attr_text,
    open_file,
    reading,
    refuse_unopenable,
    safe_flush,
    superblock_version,
)
from hpcves.run.hyperslabs import Column
from hpcves.run.layout import (
    _ARRAYS,
    _N_SCALARS,
    _SCALAR_LAYOUT,
    _SCALAR_LAYOUTS,
    DIGESTS_SINCE,
    ENDED,
    ENDED_NAMES,
    FAILED,
    FINISHED,
    FORMAT,
    FORMAT_VERSION,
    INTERRUPTED,
    MESSAGE_BYTES,
    MODEL_LIMIT,
    NOT_DECIDED,
    PENDING,
    READS_VERSIONS,
    RECORDS_SINCE,
    RUNNING,
    SNAPSHOT_RECORDS,
    STATUS_NAMES,
    TRACEBACK_BYTES,
    CaseRecord,
    GroupPlace,
    Status,
    _clip,
    _early,
    _same_value,
    capacities,
    create_layout,
    name_records,
    series_of,
    storage_bytes,
    stored_case,
    stored_N,
)
from hpcves.run.records import CaseRecords
from hpcves.run.schedule import clock
from hpcves.solver.timestepping import State

#: what the package imports from here: the case store and, from the modules it is made of, the names
#: other layers use (run/h5files.py, run/layout.py, run/hyperslabs.py, run/checksums.py)
__all__ = ["CaseStore", "HDF5_ERRORS", "OBJECT_FORMAT", "_first_line", "attr_integer", "attr_shown", "attr_text",
           "open_file", "reading", "refuse_unopenable", "safe_flush", "superblock_version", "Column", "_N_SCALARS",
           "_SCALAR_LAYOUTS", "DIGESTS_SINCE", "ENDED", "ENDED_NAMES", "FAILED", "FINISHED", "FORMAT",
           "FORMAT_VERSION", "INTERRUPTED", "MESSAGE_BYTES", "MODEL_LIMIT", "NOT_DECIDED", "PENDING", "RECORDS_SINCE",
           "RUNNING", "SNAPSHOT_RECORDS", "STATUS_NAMES", "TRACEBACK_BYTES", "CaseRecord", "GroupPlace", "Status",
           "_early", "capacities", "name_records", "series_of", "storage_bytes", "stored_case", "stored_N", "digest",
           "FileFormatError"]


class CaseStore(CaseRecords, CaseCheckpoints):
    """Reads and writes one case where ``place`` keeps it: a :class:`GroupPlace` (an h5py Group of its
    own: ``hpcves run``'s file, a format-1 campaign's case) or a row of arrays with a case dimension
    (run/blocks.py: campaign format 2). Its records and checkpoints are in run/records.py and
    run/checkpoints.py; here its creation, its checks and its metadata."""

    def __init__(self, group=None, *, place=None):
        self._place = place if place is not None else GroupPlace(group)
        #: the case's own group (None where it is a row of a block)
        self.group = getattr(self._place, "group", None)
        self.attrs = self._place.attrs
        self.where = self._place.where
        self.version = int(self.attrs.get("format_version", FORMAT_VERSION))
        self._arrays = _ARRAYS.get(self.version, State.ARRAYS)
        self._scalars = _SCALAR_LAYOUTS.get(self.version, _SCALAR_LAYOUT)
        #: low-level ids of the datasets this store writes, opened at their first use (:meth:`_id`), and
        #: how it writes a set of records (:meth:`_plan`), both shared by the rows of a block
        self._ids, self._plans = self._place.ids, self._place.plans
        #: the valid rows of timeseries and snapshots as this writer last set them (:meth:`_length`)
        self._lengths = {}
        #: {record path: (BLAKE2b of its rows 0..k, k)} for the records this writer appended from row 0
        #: on: an ended case's checksums come from the bytes it wrote instead of ~30 reads (:meth:`_append`)
        self._running = {}
        #: a checkpoint slot a resume passed over (it fails its checksums): the next checkpoint goes there
        #: (:meth:`write_checkpoint`), not over the one it resumed from
        self._overwrite_first = None
        #: {record: (BLAKE2b of its rows, their count)} that the slot a resume chose builds on (format 6)
        self._resumed_rows = {}
        #: (config text, the Case parsed from it): :attr:`case` parses a text once
        self._parsed = None
        #: the series this case records (files written before OPTIONAL_SERIES existed lack those)
        self.series_names = tuple(n for n in series_of(self.version)
                                  if n not in OPTIONAL_SERIES or self._place.has(f"timeseries/{n}"))

    # ------------------------------------------------------------------ creation
    @classmethod
    def create(cls, group, case: Case) -> "CaseStore":
        """Lay out a new case in an empty group."""
        create_layout(group, case)
        return cls(group)

    @classmethod
    def open(cls, group, where: str = "") -> "CaseStore":
        """Open an existing case, checking that it is one."""
        where = where or group.name
        if attr_text(group.attrs.get("format", "")) != FORMAT:
            raise FileFormatError(f"{where}: not an hpcves case (no format = {FORMAT!r} attribute)")
        written = group.attrs.get("format_version", -1)
        if attr_integer(written) not in READS_VERSIONS:
            raise FileFormatError(f"{where}: case format version {attr_shown(written)}, this hpcves reads "
                                  + " and ".join(map(str, READS_VERSIONS)))
        missing = [k for k in ("timeseries", "snapshots", "checkpoint", "status", "message", "progress")
                   if k not in group]
        if missing:
            raise FileFormatError(f"{where}: incomplete case, missing {', '.join(missing)}")
        return cls(group)

    # ------------------------------------------------------------------ validation
    def layout(self, case: Case) -> dict:
        """Every dataset a case holds: relative name -> (shape, numpy kind)."""
        n_samples, n_snapshots = capacities(case)
        N = stored_N(case)
        out = {"status": ((), "i"), "message": ((), "S"), "progress": ((4,), "f"),
               "timeseries/length": ((), "i"), "snapshots/length": ((), "i"),
               "snapshots/t": ((n_snapshots,), "f"), "snapshots/shift": ((n_snapshots,), "f")}
        if self._place.has("traceback"):               # absent in files written before it existed
            out["traceback"] = ((), "S")
        if self._place.has("decision"):                # likewise
            out["decision"] = ((3,), "f")
        for name in self.series_names:
            out[f"timeseries/{name}"] = ((n_samples, 2) if name == "centroid" else (n_samples,), "f")
        for name in SNAPSHOT_FIELDS:
            out[f"snapshots/{name}"] = ((n_snapshots, N), "f")
        if self.version >= DIGESTS_SINCE:
            out["timeseries/digest"] = ((len(self.series_names),), "u")
            out["snapshots/digest"] = ((len(SNAPSHOT_RECORDS),), "u")
        for slot in ("slot0", "slot1"):
            out[f"checkpoint/{slot}/meta"] = ((4,), "i")
            if self.version >= DIGESTS_SINCE:
                out[f"checkpoint/{slot}/digest"] = ((len(self._arrays) + 2,), "u")
            if self.version >= RECORDS_SINCE:
                out[f"checkpoint/{slot}/records"] = ((len(self.series_names) + len(SNAPSHOT_RECORDS),), "u")
            out[f"checkpoint/{slot}/scalars"] = ((sum(n for _, n in self._scalars),), "f")
            for name in self._arrays:
                out[f"checkpoint/{slot}/{name}"] = ((N,), "f")
        return out

    def _arrays_of(self, layout: dict) -> dict:
        """``layout`` with the records of a packed array (campaign format 3) replaced by the array: its
        case's part is a record's shape with the packed axis as wide as its records together."""
        out, packed = {}, {}
        for name, (shape, kind) in layout.items():
            column = self._place.column(name)
            if column is None:
                out[name] = (shape, kind)
                continue
            width, squeezed = packed.get(column.array, (0, None))
            packed[column.array] = (width + column.width, shape if column.squeezed else squeezed)
            out[column.array] = (column.axis, kind)
        for array, (width, shape) in packed.items():
            axis, kind = out[array]
            out[array] = (shape[:axis] + (width,) + shape[axis:], kind)
        return out

    def problems(self, expected: Case | None = None, resuming: bool = False) -> list[str]:
        """What is wrong with this case's data (empty if nothing): missing or misshapen datasets, a
        status or counters out of range, checkpoints that contradict the series, data that fail their
        checksums (format 5). Never raises.

        ``expected``: the case the file should hold (its study's); a different config is a problem.
        ``resuming``: a checkpoint slot that fails its checksums is one only when no other valid slot
        passes them (a resumed run passes over it: :meth:`read_checkpoint`).
        """
        try:
            case = self.case
        except (FileFormatError, *HDF5_ERRORS) as exc:
            return [f"its config attribute cannot be read ({_first_line(exc)})"]
        if expected is not None and case.to_dict() != expected.to_dict():
            return ["its config differs from its study's case"]
        disagree = self.parameters_disagree(case)
        if disagree:
            return disagree
        found = []
        prefix = len(self._place.prefix)
        for name, (shape, kind) in self._arrays_of(self.layout(case)).items():
            try:
                d = self._place.open(name)
                if d.shape[prefix:] != shape or d.dtype.kind != kind:
                    found.append(f"{name} has shape {d.shape[prefix:]} ({d.dtype}), expected {shape} ({kind})")
                elif any(not 0 <= i < n for i, n in zip(self._place.prefix, d.shape)):
                    found.append(f"{name} holds {d.shape[0]} cases, this one is its row {self._place.prefix[0]}")
            except HDF5_ERRORS as exc:
                found.append(f"{name} is missing or unreadable ({_first_line(exc)})")
        if found:
            return found
        try:
            schedule = clock(case)
            n_samples, n_snapshots = schedule.capacities()
            attrs = self.attrs
            if (int(attrs["sample_capacity"]), int(attrs["snapshot_capacity"]), int(attrs["N"])) != \
                    (n_samples, n_snapshots, case.numerics.N):
                found.append("its capacities or N attributes do not match its config")
            status = self.status
            if status not in STATUS_NAMES:
                found.append(f"status {status} is not a status (0 to {max(STATUS_NAMES)})")
            lengths = self.n_samples, self.n_snapshots
            for what, n, cap in (("timeseries", lengths[0], n_samples), ("snapshots", lengths[1], n_snapshots)):
                if not 0 <= n <= cap:
                    found.append(f"{what}/length = {n} lies outside [0, {cap}] (the capacity)")
            sound, failing = [], []
            for slot, meta in self._slot_meta().items():
                valid, step = int(meta[0]), int(meta[1])
                t = self._checkpoint_time(slot, step, case) if valid == 1 else math.nan
                damage = self.slot_damage(slot, records=status not in ENDED) if valid == 1 else []
                if valid == 1 and not np.array_equal(self._read(f"checkpoint/{slot}/meta"), meta):
                    continue          # a live run is rewriting this slot (it is the older one): not damage
                if valid == 1:
                    (failing if damage else sound).append(damage)
                fixed = not schedule.adaptive
                if valid not in (0, 1):
                    found.append(f"checkpoint/{slot}: validity marker {valid} is neither 0 nor 1")
                elif valid and fixed and not 0 <= step <= case.n_steps:
                    found.append(f"checkpoint/{slot}: step {step} outside [0, {case.n_steps}]")
                elif valid and not fixed and not (step >= 0 and 0 <= t <= case.run.t_end * (1 + 1e-9)):
                    found.append(f"checkpoint/{slot}: step {step} at t = {t:g}, outside [0, {case.run.t_end:g}]")
                elif valid and (int(meta[2]), int(meta[3])) not in (schedule.recorded(step, t),
                                                                    schedule.legacy().recorded(step, t)):
                    found.append(f"checkpoint/{slot}: says {int(meta[2])} samples, {int(meta[3])} snapshots "
                                 f"before step {step} (t = {t:.6g}), where the run records "
                                 f"{schedule.recorded(step, t)}")
                elif valid and fixed and t != step * case.numerics.dt:
                    found.append(f"checkpoint/{slot}: step {step} at t = {t:g}, not step * dt = "
                                 f"{step * case.numerics.dt:g}")
            code, t_decided, step_decided = self.decision
            if code not in (0, *REGIMES_BY_CODE):
                found.append(f"decision code {code} is not a regime (0 to {max(REGIMES_BY_CODE)})")
            elif code and status != FINISHED:
                found.append(f"decided ({REGIMES_BY_CODE[code]}) but {STATUS_NAMES.get(status, status)}")
            elif status == FINISHED:
                expected, before = ((schedule.recorded_through(step_decided, t_decided),
                                     schedule.legacy().recorded_through(step_decided, t_decided)) if code
                                    else (schedule.finished_counts(), schedule.legacy().finished_counts()))
                if lengths not in (expected, before):        # before: written before the coincidence fix
                    found.append(f"finished, but holds {lengths[0]} samples and {lengths[1]} snapshots of "
                                 f"{expected}" + (f" (decided at t = {t_decided:.6g})" if code else ""))
            if failing and not (resuming and sound):
                found += [f"{name} fails its checksum" for damage in failing for name in damage]
            if status in ENDED:
                found += [f"{name} fails its checksum" for name in self.data_damage()]
        except HDF5_ERRORS as exc:
            found.append(f"unreadable ({_first_line(exc)})")
        return found

    def parameters_disagree(self, case: Case) -> list[str]:
        """Where the parameter attributes of a case laid out as a group ("physics.shear_rate", ...:
        what analyze and the xarray engine read) differ from its config (what a resume runs): one of
        them was edited or damaged, and which physics the data hold is unknown. Keys an older file
        lacks are passed over; a row of a block derives its attributes from its config."""
        if self.group is None:
            return []
        found = []
        for key, value in case.flat().items():
            if key in self.attrs and not _same_value(self.attrs[key], value):
                found.append(f"its config says {key} = {value!r} but its attribute {key} = "
                             f"{attr_shown(self.attrs[key])} (edited or damaged: which physics it holds is unknown)")
        return found

    # ------------------------------------------------------------------ metadata
    @property
    def config(self) -> str:
        """The case as the TOML text it is stored as."""
        return attr_text(self.attrs["config"])

    @property
    def case(self) -> Case:
        """The case its config holds, parsed once for as long as the config text is the same."""
        text = self.config
        if self._parsed is None or self._parsed[0] != text:
            self._parsed = (text, stored_case(text, self.where))
        return self._parsed[1]

    @property
    def status(self) -> Status | int:
        """The case's :class:`Status` (a code no Status has, from a damaged file, as it is)."""
        code = int(self._read("status"))
        return Status(code) if code in Status._value2member_map_ else code

    @property
    def message(self) -> str:
        return bytes(self._read("message")[()]).decode(errors="replace")

    @property
    def traceback(self) -> str:
        if not self._place.has("traceback"):
            return ""
        return bytes(self._read("traceback")[()]).decode(errors="replace")

    @_writes
    def set_status(self, status: int, message: str | None = None, traceback: str | None = None) -> None:
        """Status, and optionally the message and traceback (written before the status); an ended
        case's data get their checksums first (:meth:`data_damage`)."""
        if status in ENDED and self.version >= DIGESTS_SINCE:
            for group, names in self._record_names():
                n = self._length(group)
                self._put(f"{group}/digest", [self._digest_of(f"{group}/{name}", n) for name in names])
        if message is not None:
            self._put("message", _clip(message, MESSAGE_BYTES))
        if traceback is not None and self._place.has("traceback"):
            self._put("traceback", _clip(traceback, TRACEBACK_BYTES))
        self._put("status", status)

    @property
    def decision(self) -> tuple[int, float, int]:
        """(regime code, t, step) of the decision that stopped the run (code 0: none; decision.py)."""
        if not self._place.has("decision"):
            return 0, math.nan, -1
        code, t, step = self._read("decision")
        return (int(code) if np.isfinite(code) else -1), float(t), (int(step) if np.isfinite(step) else -1)

    @_writes
    def set_decision(self, code: int, t: float, step: int) -> None:
        if self._place.has("decision"):
            self._put("decision", (code, t, step))

    @_writes
    def set_progress(self, t: float, t_end: float, wall: float, steps_per_second: float) -> None:
        self._put("progress", (t, t_end, wall, steps_per_second))

    @property
    def progress(self) -> np.ndarray:
        return self._read("progress")
