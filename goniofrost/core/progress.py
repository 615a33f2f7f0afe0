"""Progress bars on stderr, only when stderr is a terminal.

A bar redrawn with carriage returns is noise in a log file or a CI transcript, so every bar of
the project is made here and is off unless asked for and stderr is a terminal.
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
