"""What is left of a campaign: the work ``hpcves campaign --resume`` would do, read from its file.

``hpcves status`` says it in words, in ``--json`` and in its exit status, so that a batch
script can resubmit a job until the campaign is complete. A grid campaign is complete when
every case has ended (finished, failed or at the model's limit); a staged one (``[search]``,
``[refine]``) when, besides, its searches or refinements ask for no further stage -- found as
``--resume`` finds it, by replaying the regimes of the cases in the file.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

from hpcves.campaign.file import CampaignFile
from hpcves.campaign.refine_stages import RefineDriver, run_again
from hpcves.campaign.search_stages import SearchDriver
from hpcves.run.store import ENDED_NAMES, FAILED, STATUS_NAMES, open_file, reading

#: exit statuses of ``hpcves status`` (2: the file cannot be read, or a case is damaged)
COMPLETE, COMPLETE_WITH_FAILURES, WORK_LEFT = 0, 1, 3


@dataclass(frozen=True)
class Progress:
    """Where a campaign stands: ``complete`` (nothing left for --resume), ``left`` (what is, in
    words), ``failed`` (cases that failed, but those a refinement ran again at a larger N: --resume
    --retry-failed reruns them), ``exit_status``."""

    complete: bool
    left: str
    failed: int
    exit_status: int


def progress(path, rows: list[dict], writer: str | None) -> Progress:
    """The progress of the campaign file at ``path`` from its status rows (``read_table``) and the
    campaign writing it now (``writer``; None: none)."""
    failed = sum(r["status"] == STATUS_NAMES[FAILED] for r in rows)
    open_cases = [r for r in rows if r["status"] not in ENDED_NAMES]
    if writer is not None:
        return Progress(False, "a campaign is writing the file", failed, WORK_LEFT)
    if open_cases:
        what = ", ".join(f"{n} {s}" for s, n in Counter(r["status"] for r in open_cases).items())
        return Progress(False, f"{what} case{'s' * (len(open_cases) != 1)} to run", failed, WORK_LEFT)
    stage, again = _next_stage(path, rows)
    failed = sum(r["status"] == STATUS_NAMES[FAILED] and r["case"] not in again for r in rows)
    if stage:
        return Progress(False, f"the next stage: {stage} new case{'s' * (stage != 1)}", failed, WORK_LEFT)
    if failed:
        return Progress(True, "", failed, COMPLETE_WITH_FAILURES)
    return Progress(True, "", 0, COMPLETE)


def _next_stage(path, rows: list[dict]) -> tuple[int, frozenset]:
    """(how many cases the next stage of a staged campaign whose cases have all ended would add (0:
    none, or not a staged campaign), the failed cases that a refinement ran again at a larger N):
    its searches or refinements replayed from the file, from the verdicts it keeps where it does
    and the status and wall seconds of the ``rows`` read already."""
    with open_file(path, "r", locking=False) as h5, reading(str(path)):
        campaign = CampaignFile.check(h5, str(path))
        if campaign.mode not in ("search", "refine"):
            return 0, frozenset()
        study = campaign.stored_study(str(path))
        codes = {name: code for code, name in STATUS_NAMES.items()}
        states = {r["case"]: (codes[r["status"]], r["wall"]) for r in rows if r["status"] in codes}
        driver = (SearchDriver if study.search else RefineDriver)(study, states)
        study = driver.cases_from_file(study, campaign)
        _, new = driver.next_stage(study, campaign)
        return len(new), run_again(study)
