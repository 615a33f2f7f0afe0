"""A progress bar as a subscriber of a run's records (``goniofrost.capture.plan_runner``)."""
from __future__ import annotations

import sys

from goniofrost.capture.records import PlanEnded, RunStart, StepDone
from goniofrost.capture.steps import Assess
from goniofrost.capture.target import CONTINUE
from goniofrost.frost.stopping import REASON_PLAN as PLAN_USED_UP


class ProgressBar:
    """Count the steps of type ``counts`` that belong to a plan sample (a capture's Commit, an
    alignment's Move) up to ``total``, from ``initial`` (a resume); ``show``: the command's wish
    (``goniofrost.core.progress.show_progress``). A capture stopped early at a batch ends the bar
    at the count captured (not "15/40")."""

    def __init__(self, total: int, counts: type, *, unit: str, desc: str, show: bool, initial: int = 0) -> None:
        self.total, self.counts, self.unit, self.desc, self.show, self.initial = total, counts, unit, desc, show, initial
        self.bar = None

    def __call__(self, record) -> None:
        if isinstance(record, RunStart):
            self._open()
        elif isinstance(record, PlanEnded) and self.bar is not None:
            self.bar.close()
            self.bar = None
        elif isinstance(record, StepDone) and self.bar is not None:
            step = record.step
            if isinstance(step, self.counts) and getattr(step, "index", None) is not None:
                self.bar.update(1)
            elif isinstance(step, Assess) and step.decision not in (CONTINUE, PLAN_USED_UP):
                self.bar.total = self.bar.n
                self.bar.refresh()

    def _open(self) -> None:
        from tqdm import tqdm

        from goniofrost.core.progress import show_progress

        self.bar = tqdm(total=self.total, initial=self.initial, unit=self.unit, desc=self.desc, file=sys.stderr,
                        disable=not show_progress(self.show), dynamic_ncols=True)
