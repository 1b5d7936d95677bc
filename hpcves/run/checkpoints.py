"""A case's two checkpoint slots: written safely (invalid, written, flushed, valid), checked against
their checksums and those of the rows they build on, the newest sound one read back to resume, and
a finished case's end state or a snapshot read as another case's start -- the part of
:class:`hpcves.run.store.CaseStore` that holds the checkpoints."""
from __future__ import annotations

import hashlib
import math

import numpy as np

from hpcves.errors import FileFormatError
from hpcves.files import faults
from hpcves.model.params import Case
from hpcves.numerics.spectral import Spectral
from hpcves.run.checksums import _digest_bytes, digest
from hpcves.run.h5files import _writes
from hpcves.run.layout import (
    DIGESTS_SINCE,
    FINISHED,
    RECORDS_SINCE,
    STATUS_NAMES,
    _pack_scalars,
    _unpack_scalars,
    stored_N,
)
from hpcves.solver.timestepping import State


class CaseCheckpoints:
    """The checkpoints of a case (a mixin of :class:`hpcves.run.store.CaseStore`: it reads and writes
    through :class:`hpcves.run.records.CaseRecords`)."""

    # ------------------------------------------------------------------ checkpoints
    def _slot_meta(self):
        return {slot: self._read(f"checkpoint/{slot}/meta") for slot in ("slot0", "slot1")}

    def newest_checkpoint_slot(self) -> str | None:
        """The valid slot of the highest step (the writer's question: read through its ids)."""
        valid = [(meta[1], slot) for slot in ("slot0", "slot1")
                 if (meta := self._get(f"checkpoint/{slot}/meta"))[0] == 1]
        return max(valid)[1] if valid else None

    def slot_damage(self, slot: str, records: bool = True) -> list[str]:
        """The datasets of a checkpoint slot that fail their checksums (none in a format without them);
        with ``records`` (format 6), also the series and snapshot records whose rows the slot builds on
        fail the checksums it took of them."""
        return self._check_slot(slot, records)[0]

    def _check_slot(self, slot: str, records: bool = True) -> tuple[list[str], dict]:
        """(:meth:`slot_damage`, {record: (BLAKE2b of the rows the slot builds on, their count)} where
        ``records`` and the format keeps their checksums, else {})."""
        g = f"checkpoint/{slot}"
        if not self._place.has(f"{g}/digest"):
            return [], {}
        meta = self._read(f"{g}/meta")
        values = [*self._read_group(g, self._arrays).values(), self._read(f"{g}/scalars"), meta[1:]]
        names = [*self._arrays, "scalars", "meta"]
        damage = [f"{g}/{name}" for name, v, d in zip(names, values, self._read(f"{g}/digest")) if digest(v) != int(d)]
        if not records or damage or self.version < RECORDS_SINCE:
            return damage, {}
        hashes = self._row_hashes(int(meta[2]), int(meta[3]))
        if len(hashes) != len(self._read(f"{g}/records")):
            return damage + [f"{g}/records"], {}
        damage += [f"{path} (the {rows} rows {g} builds on)"
                   for (path, (hashed, rows)), stored in zip(hashes.items(), self._read(f"{g}/records"))
                   if int.from_bytes(hashed.digest(), "little") != int(stored)]
        return damage, hashes

    def _row_hashes(self, n_samples: int, n_snapshots: int) -> dict:
        """{record: (BLAKE2b of its first rows, their count)}: the first ``n_samples`` of every series,
        the first ``n_snapshots`` of every snapshot record, in the order of their digests; counts beyond
        the valid rows are read as they lie (a slot that claims them fails its checksums)."""
        counts = {"timeseries": max(0, n_samples), "snapshots": max(0, n_snapshots)}
        out = {}
        for group, names in self._record_names():
            for name, values in self._read_group(group, names, 0, counts[group]).items():
                hashed = hashlib.blake2b(digest_size=8)
                hashed.update(_digest_bytes(values))
                out[f"{group}/{name}"] = (hashed, counts[group])
        return out

    def _resumable_slot(self) -> tuple[str | None, str]:
        """(the newest valid slot that passes its checksums, a note when a newer one failed them and was
        passed over); raises when every valid slot fails them."""
        valid = sorted(((int(meta[1]), slot) for slot, meta in self._slot_meta().items() if meta[0] == 1),
                       reverse=True)
        failed = []
        for step, slot in valid:
            damage, hashes = self._check_slot(slot)
            if not damage:
                self._resumed_rows = hashes
                self._overwrite_first = failed[0][0] if failed else None
                note = "; ".join(f"checkpoint {s} (step {k}) fails its checksum ({', '.join(d)}): passed over"
                                 for s, k, d in failed)
                where = self.where if self.where != "/" else self._place.filename
                return slot, (f"{where}: {note}; resumed from {slot} (step {step})" if failed else "")
            failed.append((slot, step, [name.removeprefix(f"checkpoint/{slot}/") for name in damage]))
        if failed:
            raise FileFormatError(f"{self.where}: every checkpoint fails its checksum ("
                                  + "; ".join(f"{s}: {', '.join(d)}" for s, _, d in failed) + "): cannot resume")
        return None, ""

    def passed_over(self) -> str:
        """What :meth:`read_checkpoint` passes over: a note naming a newer slot that fails its checksums
        ("" where none does)."""
        return self._resumable_slot()[1]

    def _checkpoint_time(self, slot: str, step: int, case: Case) -> float:
        """The time of a slot's state (version 2 files did not store it: step * dt)."""
        if self.version == 2:
            return step * case.numerics.dt
        names = [name for name, width in self._scalars for _ in range(width)]
        return float(self._read(f"checkpoint/{slot}/scalars")[names.index("t")])

    @_writes
    def write_checkpoint(self, state: State, flush) -> None:
        """Write ``state`` (and the current sample counts) to the older slot, safely.

        ``flush`` makes the file durable between the phases (h5py File.flush).
        """
        slot = self._overwrite_first or ('slot1' if self.newest_checkpoint_slot() == 'slot0' else 'slot0')
        self._overwrite_first = None
        g = f"checkpoint/{slot}"
        self._put(f"{g}/meta", [0], 0)
        flush()
        faults.point("checkpoint")
        size, arrays = self.width, {}
        for name in self._arrays:
            value = getattr(state, name)
            if value is None:
                value = np.full(size, np.nan)
            elif value.size != size:               # N adapting: its N values first, then NaN
                value = np.concatenate([value, np.full(size - value.size, np.nan)])
            arrays[f"{g}/{name}"] = value
        stored = self._put_records(arrays)
        written = [stored[path] for path in arrays]
        written.append(_pack_scalars(state, self._scalars))
        self._put(f"{g}/scalars", written[-1])
        written.append(np.array((state.step, self._length("timeseries"), self._length("snapshots")), dtype=np.int64))
        self._put(f"{g}/meta", written[-1], 1)
        if self.version >= RECORDS_SINCE:         # the rows a resume from this slot keeps
            self._put(f"{g}/records", [self._digest_of(f"{group}/{name}", self._length(group))
                                       for group, names in self._record_names() for name in names])
        if self.version >= DIGESTS_SINCE:
            self._put(f"{g}/digest", [digest(v) for v in written])
        flush()
        faults.point("checkpoint")
        self._put(f"{g}/meta", [1], 0)
        flush()

    def end_fields(self) -> tuple[np.ndarray, np.ndarray]:
        """(theta_tilde, psi) of the state a finished case ended in -- its newest checkpoint, written at
        its end -- where a chain's next case starts (Outcome.end, read back)."""
        where = self.where
        if self.status != FINISHED:
            raise FileFormatError(f"{where}: {STATUS_NAMES.get(self.status, self.status)}, not finished: "
                                  "no end state to start from")
        found = self.read_checkpoint()
        t_end = float(self.progress[0])
        if found is None or found[0].t != t_end:
            raise FileFormatError(f"{where}: its end state (t = {t_end:g}) was not kept as a checkpoint "
                                  "(a file of an older hpcves)")
        return found[0].theta, found[0].psi

    def fields_at(self, time: float) -> tuple[np.ndarray, np.ndarray, float]:
        """(theta_tilde, psi, t) of the snapshot nearest ``time`` (the tangent angle from the positions:
        theta = arg dz/dalpha, unwrapped, minus 2 pi alpha -- without the two highest modes, which the
        positions are drawn without), or with ``time`` = -1 of the newest
        checkpoint (the end of a finished case): the state another case may start from."""
        where = self.where
        if time == -1.0:
            found = self.read_checkpoint()
            if found is None:
                raise FileFormatError(f"{where}: no checkpoint yet: no last state to start from")
            return found[0].theta, found[0].psi, found[0].t
        times = self._read("snapshots/t", 0, self.n_snapshots)
        if times.size == 0:
            raise FileFormatError(f"{where}: no snapshots: no state at t = {time:g} to start from")
        i = int(np.argmin(np.abs(times - time)))
        z = self._read("snapshots/x", i, i + 1)[0] + 1j * self._read("snapshots/y", i, i + 1)[0]
        alpha = Spectral(z.size, 1.0, backend="numpy")           # length 1: d/ds is d/dalpha
        theta_tilde = np.unwrap(np.angle(alpha.ds_complex(z))) - alpha.circle_angle
        theta_tilde -= 2.0 * np.pi * np.round(theta_tilde[0] / (2.0 * np.pi))
        return theta_tilde, self._read("snapshots/psi", i, i + 1)[0], float(times[i])

    def read_checkpoint(self) -> tuple[State, int, int] | None:
        """(state, n_samples, n_snapshots) from the newest valid slot that passes its checksums (a newer
        one that fails them is passed over: :meth:`passed_over` says so), or None."""
        slot, _ = self._resumable_slot()
        if slot is None:
            return None
        # the rows kept, verified: an ended case's checksums go on from them (:meth:`_append`)
        self._running.update({path: (hashed.copy(), rows) for path, (hashed, rows) in self._resumed_rows.items()})
        g = f"checkpoint/{slot}"
        meta = self._read(f"{g}/meta")
        scalars = _unpack_scalars(self._read(f"{g}/scalars"), self._scalars)
        N = int(scalars.pop("N")) if "N" in scalars else stored_N(self.case)
        arrays = {name: values[:N] for name, values in self._read_group(g, self._arrays).items()}
        step = int(meta[1])
        if self.version == 2:                 # a fixed-step run: its time and steps are implied
            dt = self.case.numerics.dt
            scalars.update(t=step * dt, dt_prev=dt if step >= 1 else math.nan, dt_prev2=dt if step >= 2 else math.nan)
        def kept(name):                       # levels n-1 exist from step 1 on, n-2 from step 2 on
            return not name.startswith("prev") or step >= (2 if name.startswith("prev2") else 1)
        kwargs = {name: (value if kept(name) else None) for name, value in {**arrays, **scalars}.items()}
        state = State(step=step, **kwargs)
        for name in ("theta", "psi"):
            if not np.all(np.isfinite(getattr(state, name))):
                raise FileFormatError(f"{self.where}: checkpoint {slot} holds non-finite {name}")
        return state, int(meta[2]), int(meta[3])
