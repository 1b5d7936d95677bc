"""A study that grows into its campaign file: new sweep values, a wider search, a larger budget.

A campaign file belongs to one study (``Study.fingerprint``). When the study file changes, what
changed decides: a change of what the file's cases computed (a parameter, the time rules, the
classification thresholds that steer a search or stop a run) makes another study, refused as
before; a change that only adds cases continues in the same file, every computed case kept bit
for bit:

* a grid: new sweep values (the new cases get the ids after the file's; the file's cases are
  matched to the study's by their parameters, so their ids stay what they were);
* a search: a wider range (low lower, high higher), a tighter ``rel_tol``, a larger
  ``max_cases``, other ``points``, new sweep values (new searches, numbered after the file's);
* a refinement: new values of the swept keys that are not its axes (new refinements, numbered
  after the file's); a larger ``max_cases`` or a lower ``min_resize_tail`` its fingerprint leaves
  out already. Its axes' values make the coarse grid its cells refine: not a growth.

:func:`growth` says which, on rank 0, from the file's cases and the study text it keeps.
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass

from hpcves.campaign.study import Study
from hpcves.model.params import ConfigError
from hpcves.run.store import FileFormatError, attr_text, stored_case


@dataclass(frozen=True)
class Growth:
    """How ``study`` continues in a file: as the file numbers it, and with what it adds."""

    study: Study                 # the file's cases with their ids, then the new ones (a grid); searches likewise
    new: tuple = ()              # StudyCases to lay out now (a grid's new sweep values)
    changes: tuple = ()          # what grew, in words (empty: the same study)

    @property
    def grows(self) -> bool:
        return bool(self.changes)


def growth(study: Study, campaign, where: str) -> Growth:
    """How ``study`` continues in the open campaign file ``campaign``; FileFormatError where it is
    another study, or another version of this one (what changed is named)."""
    other = campaign.name
    if other != study.name or campaign.mode != study.mode:
        raise FileFormatError(f"{where}: belongs to study {other!r} ({campaign.mode}), not to this campaign file "
                              f"({study.name!r}, {study.mode}); use another output file, or --overwrite to start over")
    if study.mode == "refine":
        return _refine(study, campaign, where)          # its refinements in the file's order, always
    if campaign.fingerprint == study.fingerprint:
        return Growth(study)
    if study.mode == "grid":
        return _grid(study, campaign, where)
    return _search(study, campaign, where)


def _changed(name: str, where: str, what: str) -> FileFormatError:
    return FileFormatError(
        f"{where}: a different version of study {name!r}: {what} changed, which changes the cases computed, not only "
        "what is added (new sweep values, a wider search range, a tighter rel_tol or a larger max_cases continue in "
        "the file); resume with the study as it was, or use another output file, or --overwrite to start over")


def _key(case) -> str:
    return json.dumps(case.significant(), sort_keys=True)


def _file_study(campaign, where: str) -> Study:
    """The study the file was made from (its stored campaign file text)."""
    try:
        return campaign.stored_study(where)
    except ConfigError as exc:
        raise FileFormatError(f"{where}: its stored study does not read with this hpcves ({exc}); "
                              "use another output file, or --overwrite to start over") from None


def _file_cases(campaign, where: str) -> list[tuple[str, object, dict]]:
    """(id, Case, swept values) of every case of the file."""
    ids = campaign.case_ids
    index = campaign.h5["index"]
    swept = [{k: float(index[k][i]) for k in campaign.sweep_keys} for i in range(len(ids))]
    if "config" in index:
        return [(cid, stored_case(attr_text(text), f"{where}: case {cid}"), values)
                for cid, text, values in zip(ids, index["config"][:len(ids)], swept)]
    return [(cid, campaign.store(cid).case, values) for cid, values in zip(ids, swept)]


def _differences(a: dict, b: dict, prefix: str = "") -> list[str]:
    """``table.key: a -> b`` for every value that differs between two nested dicts."""
    out = []
    for key in sorted(set(a) | set(b)):
        x, y = a.get(key), b.get(key)
        if isinstance(x, dict) and isinstance(y, dict):
            out += _differences(x, y, f"{prefix}{key}.")
        elif x != y:
            out.append(f"{prefix}{key}: {x!r} -> {y!r}")
    return out


def _added(old: dict, new: dict) -> str:
    """The sweep values ``new`` has beyond ``old`` ({key: values}), in words."""
    parts = [f"{key} += {', '.join(f'{v:g}' for v in values if v not in old.get(key, ()))}"
             for key, values in new.items() if set(values) - set(old.get(key, ()))]
    return "; ".join(parts)


def _grid(study: Study, campaign, where: str) -> Growth:
    if study.chain is not None or "after" in campaign.h5["index"]:
        raise _changed(study.name, where, "its cases (a chain study: they start from each other's ends, "
                                          "so none is added to one)")
    if set(campaign.sweep_keys) != set(study.sweep_keys):
        raise _changed(study.name, where,
                       f"the swept keys ({', '.join(campaign.sweep_keys)} -> {', '.join(study.sweep_keys)})")
    old = _file_study(campaign, where)
    if study.base.run.until_decided and old.analysis != study.analysis:
        raise _changed(study.name, where, "the [analysis] thresholds (they decide when a case stops)")
    if tuple(study.starts[:len(old.starts)]) != tuple(old.starts):
        names = [name for name, _ in old.starts]
        raise _changed(study.name, where, f"[starts] ({', '.join(names)} -> "
                                          f"{', '.join(name for name, _ in study.starts)}): the file numbers its "
                                          "cases' starts in its order; keep its starts as they are, in their order, "
                                          "and add new ones after them")
    pool: dict[str, list[int]] = {}             # the study's cases of each parameter set, by position
    for i, c in enumerate(study.cases):
        pool.setdefault(_key(c.case), []).append(i)
    kept, taken = [], set()
    for case_id, case, swept in _file_cases(campaign, where):
        matches = pool.get(_key(case))
        if not matches:
            raise _unmatched(study, case_id, case, swept, where)
        i = matches.pop(0)
        taken.add(i)
        kept.append(dataclasses.replace(study.cases[i], case_id=case_id))
    rest = [c for i, c in enumerate(study.cases) if i not in taken]      # in the study's order
    width = int(campaign.h5["index/case_id"].dtype.itemsize)
    if len(kept) + len(rest) > 10 ** width:
        raise FileFormatError(f"{where}: {len(kept) + len(rest)} cases do not fit its {width}-digit case ids; "
                              "use another output file for the larger study")
    new = tuple(dataclasses.replace(c, case_id=f"{len(kept) + i:0{width}d}") for i, c in enumerate(rest))
    grown = dataclasses.replace(study, cases=tuple(kept) + new)
    changes = (f"{len(new)} new case{'s' * (len(new) != 1)} ({_added(old.sweep, study.sweep)})",) if new else ()
    if not changes and grown.fingerprint != campaign.fingerprint:
        changes = ("the study file's text",)          # the same cases, written otherwise: its text is kept
    return Growth(grown, new, changes)


def _unmatched(study: Study, case_id: str, case, swept: dict, where: str) -> FileFormatError:
    """Why the file's case ``case_id`` (of ``swept`` values) has no case in ``study``: a parameter changed,
    or its values left the sweep."""
    label = ", ".join(f"{k} = {v:g}" for k, v in swept.items())
    same = [c for c in study.cases if all(c.swept.get(k) == v for k, v in swept.items())]
    if not same:
        return _changed(study.name, where, f"the sweep: its case {case_id} ({label}) is not in the study "
                                           "(a value removed?)")
    found = _differences(case.significant(), same[0].case.significant())
    hint = (" (files from before physics.bending_law ran the linear law: bending_law = \"linear\" in [physics] "
            "resumes them)" if any(d.startswith("physics.bending_law") for d in found) else "")
    return _changed(study.name, where, f"case {case_id} ({label}): " + "; ".join(found[:4])
                    + ("; ..." if len(found) > 4 else "") + hint)


def _search(study: Study, campaign, where: str) -> Growth:
    old = _file_study(campaign, where)
    was, now = old.search, study.search
    for what, a, b in (("the base case", old.base.significant(), study.base.significant()),
                       ("the time rules", dataclasses.asdict(old.times), dataclasses.asdict(study.times)),
                       ("the [analysis] thresholds (they decide where a search goes)",
                        dataclasses.asdict(old.analysis), dataclasses.asdict(study.analysis)),
                       ("what the search runs along", was.along, now.along),
                       ("[starts]", [list(s) for s in old.starts], [list(s) for s in study.starts]),
                       ("the swept keys", sorted(old.sweep), sorted(study.sweep))):
        if a != b:
            found = _differences(a, b) if isinstance(a, dict) else [f"{a!r} -> {b!r}"]
            raise _changed(study.name, where, f"{what} ({'; '.join(found[:4])})")
    narrower = [f"{name} {getattr(was, name):g} -> {getattr(now, name):g}" for name, wider in
                (("low", now.low <= was.low), ("high", now.high >= was.high), ("rel_tol", now.rel_tol <= was.rel_tol),
                 ("max_cases", now.max_cases >= was.max_cases)) if not wider]
    if narrower:
        raise _changed(study.name, where,
                       f"the search narrowed ({', '.join(narrower)}): a search only grows into its file")
    points = list(old.searches)
    lost = [p for p in points if p not in study.searches]
    if lost:
        raise _changed(study.name, where,
                       f"the sweep: its search at {lost[0]} is not in the study (a value removed?)")
    added = [p for p in study.searches if p not in points]
    grown = dataclasses.replace(study, searches=tuple(points + added))
    changes = [f"{name} {getattr(was, name):g} -> {getattr(now, name):g}"
               for name in ("low", "high", "rel_tol", "max_cases", "points")
               if getattr(was, name) != getattr(now, name)]
    if added:
        changes.append(f"{len(added)} new search{'es' * (len(added) != 1)} ({_added(old.sweep, study.sweep)})")
    if not changes and grown.fingerprint != campaign.fingerprint:
        changes.append("the study file's text")
    return Growth(grown, (), tuple(changes))


def _refine(study: Study, campaign, where: str) -> Growth:
    keys = list(study.refinements[0])
    group = campaign.h5["refinements"]
    if sorted(group) != sorted(keys):
        raise _changed(study.name, where, f"the swept keys ({', '.join(sorted(group))} -> {', '.join(keys)})")
    points = [dict(zip(keys, (float(v) for v in values))) for values in zip(*(group[k][:] for k in keys))]
    if campaign.fingerprint == study.fingerprint and points == list(study.refinements):
        return Growth(study)
    lost = [p for p in points if p not in study.refinements]
    if lost:
        raise _changed(study.name, where,
                       f"the sweep: its refinement at {lost[0]} is not in the study (a value removed?)")
    old = _file_study(campaign, where)
    as_before = dataclasses.replace(study, sweep={**study.sweep, **{k: old.sweep[k] for k in keys}})
    if as_before.fingerprint != campaign.fingerprint:
        found = [f"{k}: {old.sweep[k]} -> {study.sweep[k]}" for k in study.refine.axes
                 if old.sweep[k] != study.sweep[k]]
        raise _changed(study.name, where, ("its axes' values, the coarse grid (" + "; ".join(found) + ")") if found
                       else "its base case, time rules, [refine] plane or [analysis] thresholds")
    added = [p for p in study.refinements if p not in points]
    grown = dataclasses.replace(study, refinements=tuple(points + added))
    changes = (f"{len(added)} new refinement{'s' * (len(added) != 1)} ({_added(old.sweep, study.sweep)})",) \
        if added else ()
    if not changes and grown.fingerprint != campaign.fingerprint:
        changes = ("the study file's text",)
    return Growth(grown, (), changes)
