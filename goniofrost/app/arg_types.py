"""argparse value types shared by several commands (a bad value is argparse's one-line usage error,
before the command runs and writes anything)."""
from __future__ import annotations

import argparse


def seed(text: str) -> int:
    """``--seed``: an integer >= 0 (numpy's generators refuse a negative seed with a traceback)."""
    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, found {text!r}")
    return value
