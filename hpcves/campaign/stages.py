"""A campaign once its file is this study's and locked: the stages it runs one after the other (one
for a grid; for a search or refinement, until its driver asks for no more cases), what each shows
on the terminal, and the summary of the call."""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass

from hpcves.campaign.access import FileAccess
from hpcves.campaign.polling import bcast, wait
from hpcves.campaign.refine_stages import RefineDriver, run_again
from hpcves.campaign.scheduler import CaseResult, Master, worker_loop
from hpcves.campaign.search_stages import SearchDriver
from hpcves.campaign.state import CampaignRun
from hpcves.campaign.structure import add_stage, create_file
from hpcves.campaign.study import Study
from hpcves.errors import HpcvesError
from hpcves.files import faults
from hpcves.files.atomic import size_text
from hpcves.run.store import FAILED, FINISHED, HDF5_ERRORS, MODEL_LIMIT, PENDING, STATUS_NAMES, storage_bytes

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Summary:
    """What a campaign call did, and the state of the whole file afterwards."""

    ran: tuple                      # CaseResult of every case run in this call
    counts: dict                    # status name -> number of cases in the file
    failed: tuple                   # (case_id, message) of every failed case in the file (but those that
                                    # a refinement ran again at a larger N)
    wall: float
    searches: tuple = ()            # search (refine) studies: SearchOutcome (RefineOutcome) of every search
                                    # (refinement); empty if stopped
    not_written: str = ""           # why the campaign stopped when the file system refused a write
    run_again: int = 0              # failed cases that a refinement ran again at a larger N

    @property
    def exit_status(self) -> int:
        return 2 if self.not_written else 1 if self.failed else 0


def work_list(statuses: dict[str, int], study: Study, retry_failed: bool) -> list[tuple[str, bool]]:
    """(case_id, resume) for every case to run, most expensive first.

    Finished cases and those that reached the model's limit are skipped; failed ones too,
    unless ``retry_failed`` (then they start over, but those a refinement ran again at a larger N);
    a case that started continues from its last valid checkpoint, and one still pending starts without
    looking for one (it has none: its status is written before its first checkpoint; under relay the
    look costs two round trips to rank 0 a case).
    """
    todo = []
    again = run_again(study)
    for case_id, status in statuses.items():
        if status in (FINISHED, MODEL_LIMIT) or (status == FAILED and (not retry_failed or case_id in again)):
            continue
        todo.append((case_id, status not in (FAILED, PENDING)))
    todo.sort(key=lambda item: (-study.by_id(item[0]).cost, item[0]))
    return todo


def run_stages(run: CampaignRun, mode: str) -> Summary:
    """The campaign once the file is this study's and locked: created or continued, stage after stage."""
    study, path, comm, access, rank = run.study, run.path, run.comm, run.access, run.rank
    if mode == "create":
        if rank == 0:
            run.announce(f"creating {path} ({len(study.cases)} cases, "
                         f"{size_text(sum(storage_bytes(c.case) for c in study.cases))})", None, (0, 0))
        create_file(study, path, comm)
    h5, campaign, flush = access.open(path)
    not_written = ""
    try:
        results, outcomes = [], []
        driver = None
        if rank == 0 and study.staged:
            driver = (SearchDriver if study.search else RefineDriver)(study)
            if mode == "continue":
                run.study = driver.cases_from_file(study, campaign)
        stage, ended = 0, None
        while True:
            ran, stopped, refused = _run_stage(run, campaign, flush, mode, stage, ended)
            ended = time.perf_counter()
            results += ran
            not_written = not_written or refused
            if not run.study.staged:
                break
            access.sync(h5)                  # rank 0 is about to read the cases the others wrote
            plan, failure = ("stop",), None
            if rank == 0 and not stopped:
                try:
                    driver.ran(ran)
                    outcomes, new = driver.next_stage(run.study, campaign)
                    campaign.store_verdicts(driver.fresh)     # classified once: a resume or status reads them
                    driver.fresh.clear()
                    faults.point("verdicts-stored")
                    run.on_stage(outcomes)
                    plan = ("add", new) if new else ("done",)
                except Exception as exc:      # told to every rank, which would wait for the plan for ever
                    failure, own = exc, isinstance(exc, HpcvesError)
                    plan = ("error", type(exc) if own else RuntimeError, str(exc) if own else
                            f"{type(exc).__name__}: {exc}")
            if run.size > 1:
                plan = bcast(comm, plan)
            if failure is not None:
                raise failure
            if plan[0] == "error":
                raise plan[1](plan[2])
            if plan[0] != "add":
                break
            if rank == 0:
                run.study = run.study.with_cases(plan[1])
            if h5 is not None:
                h5.close()
                h5 = None
            refused = add_stage(path, comm, plan[1], stage + 1, run.study.source)
            if refused:
                not_written = refused
                if rank == 0:
                    log.warning("cannot add the next stage's cases: %s", refused)
                h5, campaign, flush = access.open(path)
                break
            h5, campaign, flush = access.open(path)
            stage += 1
        summary = None
        if rank == 0:
            counts = {name: 0 for name in STATUS_NAMES.values()}
            failed, again = [], run_again(run.study)
            for row in campaign.table():
                counts[row["status"]] = counts.get(row["status"], 0) + 1
                if row["status"] == "failed" and row["case"] not in again:
                    failed.append((row["case"], row["message"]))
            summary = Summary(tuple(results), counts, tuple(failed), time.perf_counter() - run.start,
                              tuple(outcomes), not_written, len(again))
    finally:
        if h5 is not None:
            try:
                h5.close()
            except HDF5_ERRORS:
                pass                               # a refused write was reported already
    if run.size > 1:
        summary = comm.bcast(summary, root=0)
    return summary


def _run_stage(run: CampaignRun, campaign, flush, mode: str, stage: int,
               ended: float | None = None) -> tuple[list[CaseResult], bool, str]:
    """Run every unfinished case of the file on every rank: (results, whether it was stopped, why the
    file system refused a write or "") on rank 0; ``ended``: when the stage before ended (perf_counter),
    to say how long rank 0 took between the two. Failed cases run again with ``run.retry_failed``, in the
    first stage only."""
    study, size = run.study, run.size
    results, stopped, refused = [], False, ""
    if run.rank == 0:
        statuses = campaign.statuses()
        todo = work_list(statuses, study, run.retry_failed and stage == 0)
        to_run = {case_id for case_id, _ in todo}
        before = [s for case_id, s in statuses.items() if case_id not in to_run]
        ended_before = (len(before), sum(1 for s in before if s == FAILED))
        if stage == 0:
            run.announce(_announcement(study, run.path, statuses, size, mode, run.access), None, (0, 0))
        if todo or not study.staged:
            line = stage_line(study, statuses, todo, stage, size)
            if ended is not None:
                line += f"; {time.perf_counter() - ended:.1f} s between stages"
            run.announce(line, len(statuses), ended_before)
        master = Master(run, campaign, flush, todo, statuses)
        results = master.run()
        stopped, refused = master.stopping, master.not_written
    else:
        worker_loop(run.comm, campaign, flush, run.stop_flag, study.analysis, study.staged)
    if size > 1:
        wait(run.comm.Ibarrier())     # everyone is done writing before the collective close (or the next stage)
    return results, stopped, refused


def _announcement(study, path, statuses, size, mode, access: FileAccess) -> str:
    """The first line of a campaign: what, where, on how many ranks."""
    verb = "new file" if mode == "create" else "continuing"
    if study.refine:
        x, y = study.refine_settings.x, study.refine_settings.y
        n = len(study.refinements)
        what = (f"{n} refinement{'s' * (n != 1)} of the regime boundaries over {x.key} x {y.key} from a "
                f"{len(x.values)} x {len(y.values)} grid (at most {study.refine.max_cases} cases each), "
                f"{len(statuses)} cases so far")
    elif study.search is None:
        what = f"{len(study.cases)} cases"
    else:
        n = len(study.searches)
        kind = "critical-shear" if study.search.along == "shear_rate" else "critical-lambda"
        what = (f"{n} {kind} search{'es' * (n != 1)} over {study.search.symbol} in [{study.search.low:g}, "
                f"{study.search.high:g}] to {study.search.rel_tol:g} (at most {study.search.max_cases} cases each), "
                f"{len(statuses)} cases so far")
    return f"campaign {study.name!r} -> {path} ({verb}): {what}; {size} rank{'s' * (size > 1)}, {access.description}"


def stage_line(study, statuses, todo, stage, size: int = 1) -> str:
    """What a stage runs: cases to run, resumed, finished and failed before -- and, where ``size`` ranks
    (rank 0 among them: it runs cases too) outnumber its cases, how many of them wait idle."""
    finished = sum(1 for s in statuses.values() if s == FINISHED)
    failed = sum(1 for s in statuses.values() if s == FAILED)
    resumed = sum(1 for case_id, resume in todo if resume)
    parts = [f"{len(todo)} to run"]
    if resumed:
        parts.append(f"{resumed} from a checkpoint")
    if finished:
        parts.append(f"{finished} finished before")
    if failed:
        parts.append(f"{failed} failed before" + ("" if any(not r for _, r in todo) else
                                                  " (--retry-failed reruns them)"))
    limited = sum(1 for s in statuses.values() if s == MODEL_LIMIT)
    if limited:
        parts.append(f"{limited} at the model's limit before")
    if study.staged and stage > 0:
        groups = len({study.by_id(case_id).search for case_id, _ in todo})
        kind = "search" if study.search else "refinement"
        parts[0] = f"stage {stage}: {len(todo)} new case{'s' * (len(todo) != 1)} for {groups} " \
                   f"{kind}{('es' if study.search else 's') * (groups != 1)}"
    line = ", ".join(parts)
    if 0 < len(todo) < size:
        line += (f"; {size - len(todo)} of the {size} ranks idle: more ranks than cases"
                 + (" in this stage" if study.staged else " (fewer ranks do the same in the same time)"))
    return line
