"""A campaign's run state: what the parts of one :func:`driver.run_campaign` call on one rank share."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from hpcves.campaign.access import FileAccess
from hpcves.campaign.study import Study


@dataclass
class CampaignRun:
    """One call of :func:`run_campaign` on one rank: what its parts share. ``study`` grows as a staged
    study adds its cases (on rank 0, which keeps the cases)."""

    study: Study
    path: Path
    comm: object                          # None: this process alone
    access: FileAccess
    retry_failed: bool
    stop_flag: Callable[[], bool]
    display: Callable | None
    announce: Callable[[str, int | None, tuple[int, int]], None]
    on_stage: Callable[[list], None]
    start: float = field(default_factory=time.perf_counter)

    @property
    def size(self) -> int:
        return 1 if self.comm is None else self.comm.Get_size()

    @property
    def rank(self) -> int:
        return 0 if self.comm is None else self.comm.Get_rank()
