"""Progress bars on stderr, drawn only when asked for and stderr is a terminal (a bar redrawn with
carriage returns is noise in a log).
"""
from __future__ import annotations

import sys


def show_progress(asked: bool | None) -> bool:
    """True when a bar was asked for and stderr is a terminal."""
    return bool(asked) and sys.stderr.isatty()


def progress_bar(iterable=None, *, asked: bool | None = True, **options):
    """A tqdm bar on stderr (``options`` as tqdm's), disabled unless ``show_progress(asked)``."""
    from tqdm import tqdm

    options.setdefault("file", sys.stderr)
    return tqdm(iterable, disable=not show_progress(asked), **options)


class StageBar:
    """One bar over the named stages of a long step (``train``: tabulating, mapping, ...), drawn
    as "DESC k/n: STAGE" above the stage's own bar, if it has one; off unless ``show_progress``.

    ``stage(name)`` moves to the stage ``name`` (one of ``stages``); ``close()`` ends the bar.
    """

    def __init__(self, desc: str, stages, *, asked: bool | None = True) -> None:
        self.desc, self.stages = desc, tuple(stages)
        self._bar = progress_bar(total=len(self.stages), desc=desc, asked=asked, unit="stage", leave=False,
                                 bar_format="{desc} ({elapsed})")

    def stage(self, name: str) -> None:
        """Show stage ``name`` (its place among ``stages``: 1-based)."""
        k = self.stages.index(name) + 1
        self._bar.n = k
        self._bar.set_description_str(f"{self.desc} {k}/{len(self.stages)}: {name}", refresh=True)

    def close(self) -> None:
        self._bar.close()

    def __enter__(self) -> "StageBar":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
